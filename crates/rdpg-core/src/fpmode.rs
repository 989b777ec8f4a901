//! The CPU's treatment of subnormal floats, per thread.
//!
//! Learners want subnormals flushed to zero (FTZ/DAZ): training drives LSTM gate derivatives
//! and Adam moments into the subnormal range, where x86 arithmetic is up to 100x slower.
//! Environments must not: their arithmetic has to stay IEEE's to match Gymnasium bit for bit.
//! [`set_flush_denormal`] switches a thread's mode; [`with_ieee_denormals`] runs physics in IEEE
//! mode whatever the calling thread's mode is (every registered environment's `reset` and
//! `step` go through it).

#[cfg(target_arch = "x86_64")]
const FTZ_DAZ: u32 = (1 << 15) | (1 << 6);

#[cfg(target_arch = "x86_64")]
fn read_mxcsr() -> u32 {
    let mut csr: u32 = 0;
    // SAFETY: stmxcsr stores this thread's SSE control register into `csr`.
    unsafe { std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack)) };
    csr
}

#[cfg(target_arch = "x86_64")]
fn write_mxcsr(csr: u32) {
    // SAFETY: ldmxcsr loads this thread's SSE control register; callers only change the FTZ
    // and DAZ bits of a value read from it, which affect how subnormals are treated.
    unsafe { std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, readonly)) };
}

/// Makes the CPU flush subnormal floats to zero (`on`) or treat them as IEEE says (`!on`) on
/// the calling thread (the x86 MXCSR flags FTZ and DAZ; a no-op elsewhere). Threads created
/// afterwards by this thread inherit the mode (Linux copies the FPU state on `clone`). Returns
/// whether the flags exist on this CPU architecture. This is what
/// `torch.set_flush_denormal(True)` does.
pub fn set_flush_denormal(on: bool) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        let csr = read_mxcsr();
        write_mxcsr(if on { csr | FTZ_DAZ } else { csr & !FTZ_DAZ });
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = on;
        false
    }
}

/// Whether the calling thread flushes subnormals to zero.
pub fn flushes_denormals() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        read_mxcsr() & FTZ_DAZ != 0
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Runs `f` with IEEE subnormals on the calling thread, then restores the thread's mode.
pub fn with_ieee_denormals<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        let csr = read_mxcsr();
        if csr & FTZ_DAZ == 0 {
            return f();
        }
        write_mxcsr(csr & !FTZ_DAZ);
        let r = f();
        write_mxcsr(csr);
        r
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        f()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_switch_and_physics_runs_in_ieee_mode() {
        let tiny = std::hint::black_box(1e-40f32); // subnormal
        set_flush_denormal(true);
        if flushes_denormals() {
            assert_eq!(std::hint::black_box(tiny) * 1.0, 0.0);
            let inside = with_ieee_denormals(|| std::hint::black_box(tiny) * 1.0);
            assert_eq!(inside, tiny);
            assert!(flushes_denormals(), "the mode is restored");
        }
        set_flush_denormal(false);
        assert!(!flushes_denormals());
        assert_eq!(std::hint::black_box(tiny) * 1.0, tiny);
        assert_eq!(with_ieee_denormals(|| tiny * 1.0), tiny);
    }
}
