//! The C allocator's settings for processes that train.
//!
//! libtorch allocates the tensors of every update with the C allocator and frees them at the
//! end of it. glibc serves blocks above its mmap threshold with fresh `mmap`s and returns the
//! free top of the heap to the kernel above its trim threshold, so the same megabytes are
//! unmapped and faulted in again (and zeroed by the kernel) on every update: `perf` put 15 % of a
//! walker-rdpg update in the kernel's page-fault path, 4.6 % after [`keep_freed_memory`]
//! (BENCHMARKS.md, "The C allocator"). Numbers do not change: libtorch aligns every block to
//! 64 bytes either way.

/// glibc's `mallopt` parameter numbers (`malloc.h`).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const M_TRIM_THRESHOLD: i32 = -1;
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const M_MMAP_THRESHOLD: i32 = -3;

/// Blocks below this come from the heap (glibc's dynamic threshold stops at 32 MiB).
pub const MMAP_THRESHOLD: usize = 64 << 20;
/// Free memory at the top of the heap kept for reuse, at most.
pub const TRIM_THRESHOLD: usize = 512 << 20;

#[cfg(all(target_os = "linux", target_env = "gnu"))]
extern "C" {
    fn mallopt(param: i32, value: i32) -> i32;
}

/// Makes glibc keep freed memory for reuse (mmap threshold [`MMAP_THRESHOLD`], trim threshold
/// [`TRIM_THRESHOLD`]) unless the environment variable `RDPG_MALLOC` is `default`. Call it once
/// at the start of a process, before the allocations it should govern. Returns whether the
/// settings were applied (false elsewhere than on glibc, or when opted out).
pub fn keep_freed_memory() -> bool {
    if opted_out() {
        return false;
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only changes two of glibc's allocator parameters; both values are
        // positive and within glibc's accepted ranges.
        unsafe {
            mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD as i32) == 1
                && mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD as i32) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

/// Whether `RDPG_MALLOC=default` asks for glibc's own settings.
fn opted_out() -> bool {
    std::env::var("RDPG_MALLOC").is_ok_and(|v| v == "default")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glibc_accepts_the_settings() {
        // Process-wide, but harmless for the other tests of this binary. mallopt returns 0 for a
        // value glibc rejects.
        let applied = keep_freed_memory();
        assert_eq!(
            applied,
            cfg!(all(target_os = "linux", target_env = "gnu")) && !opted_out()
        );
    }
}
