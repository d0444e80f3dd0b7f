//! The engine's worker threads: they take the requests whose cost grows with their
//! payload off Zenoh's callback threads.
//!
//! One thread per core, sharing a bounded queue: a request that finds the queue full is
//! refused at once (`limit_exceeded`) instead of waiting behind work it cannot see the end
//! of, and a request that waited past its deadline is refused by the worker that takes
//! it. Batches still spread over every core inside a request (rayon).

use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread;

/// Requests waiting for a worker, at most.
const QUEUE: usize = 1024;

pub(crate) struct Workers<J> {
    queue: SyncSender<J>,
}

impl<J: Send + 'static> Workers<J> {
    /// Starts one worker per core, each running `work` on the jobs it takes. The workers
    /// end when this pool is dropped and its queue drained.
    pub fn spawn(name: &str, work: impl Fn(J) + Send + Sync + 'static) -> std::io::Result<Self> {
        let (queue, jobs) = mpsc::sync_channel::<J>(QUEUE);
        let jobs = Arc::new(Mutex::new(jobs));
        let work = Arc::new(work);
        let count = thread::available_parallelism().map_or(2, |n| n.get());
        for index in 0..count {
            let (jobs, work) = (Arc::clone(&jobs), Arc::clone(&work));
            thread::Builder::new()
                .name(format!("ciflow-engine-{name}-{index}"))
                .spawn(move || {
                    while let Some(job) = next(&jobs) {
                        work(job);
                    }
                })?;
        }
        Ok(Self { queue })
    }

    /// Queues a job; gives it back if the queue is full or the workers are gone.
    pub fn submit(&self, job: J) -> Result<(), J> {
        self.queue.try_send(job).map_err(|error| match error {
            TrySendError::Full(job) | TrySendError::Disconnected(job) => job,
        })
    }
}

/// The next job; `None` once the pool is dropped and the queue drained.
fn next<J>(jobs: &Mutex<Receiver<J>>) -> Option<J> {
    jobs.lock().unwrap_or_else(|p| p.into_inner()).recv().ok()
}
