//! Stop requests for `rdpg train` (Ctrl-C, SIGTERM, SIGHUP), taken off the computing threads.
//!
//! A signal handler runs on whichever thread the kernel interrupts, with a signal frame pushed
//! onto that thread's stack. libtorch's oneDNN LSTM backward (AVX-512, torch 2.11) does not
//! survive being interrupted: a signal landing inside it corrupts the heap (glibc aborts
//! with "corrupted size vs. prev_size while consolidating", or the process segfaults) —
//! reproduced within seconds by `scripts/repro/onednn_lstm_signals.py`, and the likely cause of
//! the rare aborts of recurrent runs stopped with Ctrl-C or SIGTERM (RESULTS.md). It is oneDNN's
//! bug #4845 (its generated f32 GEMM kernels point `rsp` at the heap while they run), fixed in
//! oneDNN 3.11.2; torch 2.11.0 ships oneDNN 3.10.2. So, on Unix, no thread is ever interrupted:
//! the three signals are blocked in the main thread before any other thread exists (every later
//! thread, libtorch's included, inherits the mask), and one thread, `rdpg-signals`, takes them
//! synchronously with `sigwait`. (Linux keeps a blocked signal
//! pending even when its disposition is "ignore", as under `nohup` or in a script's background
//! job, so those runs stop on the signals as they did with a handler; systems that discard
//! ignored signals, e.g. macOS, do not.)

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{Context, Result};

/// Name of the thread that takes the stop signals (Unix).
#[cfg(unix)]
const SIGNAL_THREAD: &str = "rdpg-signals";

/// Routes Ctrl-C, SIGTERM and SIGHUP to `stop`: the first sets it (the training loop then
/// finishes its step, saves and exits 130). Once stopping, a Ctrl-C exits at once with 130 (a
/// person who will not wait); a repeated SIGTERM or SIGHUP changes nothing: schedulers, session
/// ends and sweep drivers may each send one, and none of them means "drop the save". Call it
/// from the main thread before any other thread is spawned.
pub fn install(stop: Arc<AtomicBool>) -> Result<()> {
    #[cfg(unix)]
    {
        use nix::sys::signal::{SigSet, Signal};
        let mut set = SigSet::empty();
        for s in [Signal::SIGINT, Signal::SIGTERM, Signal::SIGHUP] {
            set.add(s);
        }
        set.thread_block()
            .context("blocking the stop signals in the training threads")?;
        std::thread::Builder::new()
            .name(SIGNAL_THREAD.into())
            .spawn(move || {
                // (sigwait can only fail on an invalid set, which this is not.)
                while let Ok(signal) = set.wait() {
                    on_signal(&stop, signal == Signal::SIGINT);
                }
            })
            .context("starting the signal thread")?;
    }
    #[cfg(not(unix))]
    ctrlc::set_handler(move || on_signal(&stop, true)).context("installing the signal handler")?;
    Ok(())
}

/// `ctrl_c`: the signal is Ctrl-C (SIGINT), the one a person sends twice to leave now.
fn on_signal(stop: &AtomicBool, ctrl_c: bool) {
    if !stop.swap(true, Ordering::SeqCst) {
        return;
    }
    if ctrl_c {
        // The last checkpoint on disk stays whole: checkpoints are committed by rename.
        eprintln!("second interrupt: exiting without saving (the last checkpoint is intact)");
        std::process::exit(130);
    }
    eprintln!("already stopping: saving first (Ctrl-C to exit without saving)");
}
