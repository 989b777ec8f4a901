//! Actor-critic learners for rdpg on libtorch (through `tch`): the recurrent deterministic
//! policy gradient (RDPG) of Song et al. (ICARCV 2018) and its feed-forward (DDPG) variant.
//!
//! This is the only crate of the workspace that names the tensor library.
//!
//! * [`RdpgConfig`]: hyper-parameters (serde, validated).
//! * [`nets`]: actor and critic networks (lidar convolution trunk or MLP, LSTM or FC core).
//! * [`RdpgAgent`]: acting ([`RdpgAgent::act`] with an [`ActorState`]), the update of
//!   Algorithm 1 on an [`rdpg_core::SequenceBatch`] ([`RdpgAgent::update`]), checkpoints
//!   ([`RdpgAgent::save`] / [`RdpgAgent::load`], optimiser moments included).
//! * [`bench`](mod@bench): synthetic BipedalWalker-shaped batches and an update-throughput benchmark.
//!
//! # Linking (for binary crates)
//!
//! tch links libtorch dynamically. A binary depending on this crate needs, in its own
//! `build.rs` (link arguments of a library do not reach dependents):
//!
//! ```text
//! let lib = std::env::var("DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB").unwrap();
//! println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
//! if std::env::var("DEP_RDPG_AGENTS_TORCH_HAS_CUDA").as_deref() == Ok("1") {
//!     println!("cargo:rustc-link-arg=-Wl,--no-as-needed");
//!     println!("cargo:rustc-link-arg=-ltorch_cuda");
//! }
//! ```
//!
//! (`DEP_RDPG_AGENTS_TORCH_*` are exported by this crate's build script through
//! `links = "rdpg_agents_torch"`, to direct dependents only.) Without the `--no-as-needed
//! -ltorch_cuda` pair the linker drops `libtorch_cuda.so` and CUDA is never available.

#![warn(missing_docs)]

pub mod adam;
pub mod bench;
pub mod config;
pub mod error;
pub mod inject;
pub mod nets;
pub mod ppo;
pub mod rdpg;
pub mod train;

pub use config::{DeviceSpec, RdpgConfig, ScanMethod, TargetNoise, Trunk};
pub use error::{AgentError, Result};
pub use rdpg::{ActorState, PhaseTimes, RdpgAgent, UpdateStats};
pub use train::memory_task_config;

/// Whether libtorch reports a usable CUDA device.
pub fn cuda_available() -> bool {
    tch::Cuda::is_available()
}

/// Sets the number of intra-op CPU threads libtorch uses (process-wide).
pub fn set_num_threads(n: usize) {
    tch::set_num_threads(n as i32);
}

/// Makes the CPU flush denormal (subnormal) floats to zero on the calling thread (the x86
/// MXCSR flags FTZ and DAZ; a no-op elsewhere). Returns whether the flags were set.
///
/// Training drives some values (LSTM gate derivatives, Adam moments of tiny gradients) into the
/// subnormal range, where x86 arithmetic is up to 100x slower: without this, an update on the
/// memory task slows down several-fold as training goes on. This is what
/// `torch.set_flush_denormal(True)` does; like it, it affects only the calling thread, so call it
/// on the thread that acts and updates (the trainer does, see [`RdpgConfig::flush_denormal`]).
pub fn set_flush_denormal(on: bool) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        const FTZ_DAZ: u32 = (1 << 15) | (1 << 6);
        let mut csr: u32 = 0;
        // SAFETY: stmxcsr/ldmxcsr read and write the SSE control register of this thread;
        // FTZ and DAZ only change how subnormal results and inputs are treated.
        unsafe {
            std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack));
            csr = if on { csr | FTZ_DAZ } else { csr & !FTZ_DAZ };
            std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, readonly));
        }
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = on;
        false
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn links_and_runs() {
        let t = tch::Tensor::from_slice(&[1.0f32, 2.0]).sum(tch::Kind::Float);
        assert_eq!(t.double_value(&[]), 3.0);
        eprintln!("cuda available: {}", super::cuda_available());
    }
}
