//! Hand-offs between threads that wait for each other tens of microseconds at a time.

use std::sync::mpsc::{Receiver, RecvError, TryRecvError};
use std::time::{Duration, Instant};

/// How long [`recv_spin`] spins before it blocks.
pub const SPIN: Duration = Duration::from_micros(200);

/// Receives from `rx`, spinning up to [`SPIN`] before blocking: the other side usually answers
/// within tens of microseconds, and waking a parked thread (a futex round trip, slow on virtual
/// machines) would cost as much.
pub fn recv_spin<T>(rx: &Receiver<T>) -> Result<T, RecvError> {
    let start = Instant::now();
    loop {
        match rx.try_recv() {
            Ok(v) => return Ok(v),
            Err(TryRecvError::Disconnected) => return Err(RecvError),
            Err(TryRecvError::Empty) => {
                if start.elapsed() > SPIN {
                    return rx.recv();
                }
                std::hint::spin_loop();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn receives_before_and_after_the_spin_and_reports_a_closed_channel() {
        let (tx, rx) = std::sync::mpsc::channel();
        tx.send(1).unwrap();
        assert_eq!(recv_spin(&rx), Ok(1));
        let late = std::thread::spawn(move || {
            std::thread::sleep(SPIN * 5);
            tx.send(2).unwrap();
        });
        assert_eq!(recv_spin(&rx), Ok(2));
        late.join().unwrap();
        assert_eq!(recv_spin(&rx), Err(RecvError));
    }
}
