//! How an engine process is scheduled: as a batch job that yields to the processes it
//! serves.
//!
//! [`run_as_batch`] puts the calling thread, and every thread it starts afterwards (Linux
//! threads inherit it), under the `SCHED_BATCH` policy: the same share of the CPU as any
//! other thread at the same nice value, but a thread that wakes up does not preempt the
//! one running on its core. `ciflow serve` calls it first, so all of the engine's threads
//! — Zenoh's, the workers, the stepping pool — run that way.
//!
//! Why: with no spare core (`bench/scale_out.sh`: two engines, each pinned to one of the
//! two cores, and their client sharing those cores), a client that had just sent its first
//! engine a request was preempted by that engine's threads waking to serve it, so the
//! second engine got its request a scheduler slice (1.5–2 ms) later in 14–38 % of the
//! steps (the client a Zenoh peer of the engines); with the engines as batch processes, in
//! 3–9 % (`bench/README.md`, "Two engines"). A waiting engine still runs as soon as its
//! core is free.

use std::io;

/// Runs the calling thread, and the threads it starts from now on, as batch threads
/// (`SCHED_BATCH`), if it runs under the normal policy: a policy chosen for the process
/// (`chrt -f` for a real-time engine, `chrt -i`, …) is kept. A no-op elsewhere than on
/// Linux.
pub fn run_as_batch() -> io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        if current_policy()? != libc::SCHED_OTHER {
            return Ok(());
        }
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: `param` outlives the call; pid 0 is the calling thread; SCHED_BATCH takes
        // priority 0 and needs no privilege.
        if unsafe { libc::sched_setscheduler(0, libc::SCHED_BATCH, &param) } != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    Ok(())
}

/// The calling thread's scheduling policy (`SCHED_OTHER`, `SCHED_BATCH`, …).
#[cfg(target_os = "linux")]
fn current_policy() -> io::Result<libc::c_int> {
    // SAFETY: pid 0 queries the calling thread; no pointer is passed.
    match unsafe { libc::sched_getscheduler(0) } {
        -1 => Err(io::Error::last_os_error()),
        policy => Ok(policy),
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    fn policy() -> libc::c_int {
        current_policy().unwrap()
    }

    #[test]
    fn threads_started_after_it_are_batch_threads_and_others_are_not() {
        let (own, child) = std::thread::spawn(|| {
            run_as_batch().unwrap();
            (policy(), std::thread::spawn(policy).join().unwrap())
        })
        .join()
        .unwrap();
        assert_eq!((own, child), (libc::SCHED_BATCH, libc::SCHED_BATCH));
        // Negative control: a thread started by one that did not call it keeps the normal
        // policy, so the check above can tell the two apart.
        assert_eq!(
            std::thread::spawn(policy).join().unwrap(),
            libc::SCHED_OTHER
        );
    }

    #[test]
    fn a_policy_chosen_before_is_kept() {
        let kept = std::thread::spawn(|| {
            let param = libc::sched_param { sched_priority: 0 };
            // SAFETY: as in `run_as_batch`; SCHED_IDLE needs no privilege either.
            let set = unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) };
            assert_eq!(set, 0);
            run_as_batch().unwrap();
            policy()
        })
        .join()
        .unwrap();
        assert_eq!(kept, libc::SCHED_IDLE);
    }
}
