//! Subnormal floats are flushed in libtorch's worker threads too, not only on the thread that
//! set the mode: a trainer sets it before any tensor work, so the worker threads libtorch
//! creates at its first parallel region inherit it. (Its own test binary: the worker threads
//! of a process are created once.)

use rdpg_agents::rdpg::{ExplorationConfig, OffPolicyConfig, OffPolicyTrainer};
use rdpg_agents::{RdpgConfig, TrainConfig};
use tch::{Device, Kind, Tensor};

#[test]
fn libtorch_worker_threads_flush_denormals_after_a_trainer_is_built() {
    let train = TrainConfig {
        env: "Pendulum-v1".into(),
        eval_every: 0,
        ..TrainConfig::default()
    };
    let off = OffPolicyConfig {
        exploration: ExplorationConfig::None,
        ..OffPolicyConfig::default()
    };
    let agent = RdpgConfig {
        num_threads: Some(2),
        ..rdpg_agents::rdpg::memory_task_config(true)
    };
    let _t = OffPolicyTrainer::new(train, off, agent).unwrap();
    // 4M subnormal inputs: the element-wise product is split over both threads (grain size
    // 32768); a thread without FTZ/DAZ would leave its half at 1e-40.
    let x = Tensor::full([1 << 22], 1e-40, (Kind::Float, Device::Cpu));
    let y = std::hint::black_box(&x) * 3.0;
    let kept = y.ne(0.0).sum(Kind::Int64).int64_value(&[]);
    assert_eq!(kept, 0, "{kept} subnormal products were not flushed");
}
