//! A second thread kept for an agent's life, for the two-thread phases of its update
//! (`parallel_twins`): starting a scoped thread per phase cost about 0.1 ms each, up to three
//! times per update, and left no way to let work run on past the phase that started it.
//!
//! A job is a `'static` closure (it owns shallow handles of the tensors it reads or writes).
//! The thread runs each job with the caller's flush-to-zero mode and libtorch thread count
//! (both are per-thread settings: without the thread count, OpenMP/MKL would start a team of
//! one thread per core for the job's first kernel). A panic in a job is raised again in the
//! caller by [`SideThread::finish`].

use std::any::Any;
use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;

use rdpg_core::spin::recv_spin;

type Job = Box<dyn FnOnce() -> Box<dyn Any + Send> + Send>;
type Outcome = std::thread::Result<Box<dyn Any + Send>>;

/// The second thread and the job it is running, if any.
#[derive(Debug)]
pub struct SideThread {
    tx: Option<Sender<(bool, i32, Job)>>,
    rx: Receiver<Outcome>,
    handle: Option<JoinHandle<()>>,
    running: bool,
}

impl SideThread {
    /// Starts the thread (it waits for jobs).
    ///
    /// # Panics
    /// If the operating system cannot start a thread.
    #[allow(
        clippy::expect_used,
        reason = "the OS refusing a thread is no input of rdpg's; the update cannot go on without it"
    )]
    pub fn new() -> Self {
        let (tx, jobs) = channel::<(bool, i32, Job)>();
        let (done, rx) = channel::<Outcome>();
        let handle = std::thread::Builder::new()
            .name("rdpg-side".into())
            .spawn(move || {
                let mut threads = None;
                while let Ok((ftz, n, job)) = recv_spin(&jobs) {
                    rdpg_core::fpmode::set_flush_denormal(ftz);
                    if threads != Some(n) {
                        tch::set_num_threads(n);
                        threads = Some(n);
                    }
                    let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(job));
                    if done.send(out).is_err() {
                        return;
                    }
                }
            })
            .expect("cannot start the update's second thread");
        Self {
            tx: Some(tx),
            rx,
            handle: Some(handle),
            running: false,
        }
    }

    /// Starts `job` on the side thread with flush-to-zero `ftz` and the calling thread's
    /// libtorch thread count. Collect its result with [`SideThread::finish`].
    ///
    /// # Panics
    /// If a job is already running (each `start` pairs with one `finish`).
    #[allow(
        clippy::expect_used,
        reason = "the sender and the side thread live until drop"
    )]
    pub fn start<B: Send + 'static>(
        &mut self,
        ftz: bool,
        job: impl FnOnce() -> B + Send + 'static,
    ) {
        assert!(
            !self.running,
            "SideThread::start: the previous job was not finished"
        );
        let job: Job = Box::new(move || Box::new(job()) as Box<dyn Any + Send>);
        let threads = tch::get_num_threads();
        self.tx
            .as_ref()
            .expect("the sender lives until drop")
            .send((ftz, threads, job))
            .expect("the side thread lives until drop");
        self.running = true;
    }

    /// Waits for the job started last and returns its result; a panic in the job is raised
    /// again here.
    ///
    /// # Panics
    /// If no job is running, if `B` is not the job's result type, or if the job panicked.
    #[allow(
        clippy::expect_used,
        reason = "the side thread lives until drop and sends one result per job"
    )]
    pub fn finish<B: 'static>(&mut self) -> B {
        assert!(self.running, "SideThread::finish: no job was started");
        self.running = false;
        let out = recv_spin(&self.rx).expect("the side thread lives until drop");
        match out {
            Ok(b) => *b
                .downcast::<B>()
                .expect("SideThread::finish: wrong result type"),
            Err(panic) => std::panic::resume_unwind(panic),
        }
    }

    /// Whether a job was started and not yet finished.
    pub fn running(&self) -> bool {
        self.running
    }

    /// Runs `main` here and `side` on the side thread at the same time; returns both results.
    pub fn run<A, B: Send + 'static>(
        &mut self,
        ftz: bool,
        main: impl FnOnce() -> A,
        side: impl FnOnce() -> B + Send + 'static,
    ) -> (A, B) {
        self.start(ftz, side);
        let a = std::panic::catch_unwind(std::panic::AssertUnwindSafe(main));
        let b = self.finish::<B>();
        match a {
            Ok(a) => (a, b),
            Err(panic) => std::panic::resume_unwind(panic),
        }
    }
}

impl Default for SideThread {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for SideThread {
    fn drop(&mut self) {
        if self.running {
            let _ = recv_spin(&self.rx);
        }
        drop(self.tx.take());
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_jobs_in_order_with_the_callers_settings_and_reraises_panics() {
        let mut side = SideThread::new();
        tch::set_num_threads(1);
        let (a, (b, ftz, n)) = side.run(
            true,
            || 1,
            || {
                (
                    2,
                    rdpg_core::fpmode::flushes_denormals(),
                    tch::get_num_threads(),
                )
            },
        );
        assert_eq!((a, b, n), (1, 2, 1));
        assert_eq!(ftz, cfg!(target_arch = "x86_64"));
        side.start(false, rdpg_core::fpmode::flushes_denormals);
        assert!(side.running());
        assert!(!side.finish::<bool>());
        let t = tch::Tensor::from_slice(&[1.0f32, 2.0]);
        let t1 = t.shallow_clone();
        side.start(false, move || {
            let _ = t1.shallow_clone().g_mul_scalar_(3.0);
        });
        side.finish::<()>();
        assert_eq!(Vec::<f32>::try_from(&t).unwrap(), [3.0, 6.0]);
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            side.run(false, || (), || panic!("side job failed"))
        }));
        assert!(caught.is_err());
        assert_eq!(side.run(false, || 3, || 4), (3, 4), "usable after a panic");
    }
}
