//! [`Trail`]: the points an environment visited this episode, which `render` draws
//! behind the robot.
//!
//! A trail holds an episode's points: 16 kB for the limit cycle's 1 000 steps, more than
//! the rest of the environment. An engine turns trails off for the environments of a
//! batch, which nobody watches one by one, and a trail that records reserves the whole
//! episode at reset, so that steps never grow it.

/// The points visited this episode, while recording (on when made).
#[derive(Clone, Debug)]
pub struct Trail<P> {
    points: Vec<P>,
    recording: bool,
}

impl<P> Default for Trail<P> {
    fn default() -> Self {
        Self {
            points: Vec::new(),
            recording: true,
        }
    }
}

impl<P> Trail<P> {
    /// Starts an episode at `first`, with room for `max_episode_steps` more points. The
    /// memory is kept from one episode to the next.
    pub fn start(&mut self, first: P, max_episode_steps: u32) {
        self.points.clear();
        if self.recording {
            self.points.reserve(max_episode_steps as usize + 1);
            self.points.push(first);
        }
    }

    /// Adds the point a step reached.
    pub fn push(&mut self, point: P) {
        if self.recording {
            self.points.push(point);
        }
    }

    /// Starts or stops recording; stopping frees the points (a stopped trail is empty).
    pub fn record(&mut self, recording: bool) {
        self.recording = recording;
        if !recording {
            self.points = Vec::new();
        }
    }

    pub fn points(&self) -> &[P] {
        &self.points
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_an_episode_in_room_reserved_at_the_start() {
        let mut trail = Trail::default();
        trail.start(0, 10);
        let reserved = trail.points.capacity();
        assert!(reserved >= 11);
        (1..=10).for_each(|p| trail.push(p));
        assert_eq!(trail.points(), (0..=10).collect::<Vec<_>>());
        assert_eq!(trail.points.capacity(), reserved, "steps did not grow it");
        trail.start(7, 10);
        assert_eq!(trail.points(), [7]);
        assert_eq!(
            trail.points.capacity(),
            reserved,
            "kept for the next episode"
        );
    }

    #[test]
    fn a_trail_that_does_not_record_holds_nothing() {
        let mut trail = Trail::default();
        trail.start(0, 1000);
        trail.push(1);
        trail.record(false);
        assert_eq!((trail.points().len(), trail.points.capacity()), (0, 0));
        trail.start(0, 1000);
        trail.push(1);
        assert_eq!((trail.points().len(), trail.points.capacity()), (0, 0));
        trail.record(true);
        trail.push(2);
        trail.start(3, 5);
        trail.push(4);
        assert_eq!(trail.points(), [3, 4]);
    }
}
