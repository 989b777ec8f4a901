//! Where the time of one update goes, for a given config: `profile_update [memory|paper]`.
use rdpg_agents::bench::synthetic_batch;
use rdpg_agents::{memory_task_config, set_num_threads, RdpgAgent, RdpgConfig};

fn main() {
    let which = std::env::args().nth(1).unwrap_or_else(|| "memory".into());
    set_num_threads(2);
    let (cfg, obs, act) = if which == "memory" {
        (memory_task_config(false), 2, 1)
    } else {
        (
            RdpgConfig {
                device: rdpg_agents::DeviceSpec::Cpu,
                ..RdpgConfig::default()
            },
            24,
            4,
        )
    };
    let mut cfg = cfg;
    if let Ok(t) = std::env::var("THREADS") {
        set_num_threads(t.parse().unwrap());
    }
    if std::env::var("LEAN").is_ok() {
        cfg.tau = 0.0;
        cfg.actor_uses_updated_critic = false;
    }
    if std::env::args().nth(2).as_deref() == Some("masked") {
        cfg.scan_method = rdpg_agents::ScanMethod::MaskedLoop;
    }
    let mut agent = RdpgAgent::new(cfg.clone(), obs, act, 0).unwrap();
    let mut rng = rdpg_core::rng::NpRng::from_seed(0);
    let batch = synthetic_batch(
        cfg.batch_size,
        cfg.scan_len,
        cfg.opt_len,
        obs,
        act,
        0.1,
        &mut rng,
    );
    for _ in 0..5 {
        agent.update(&batch);
    }
    agent.set_profiling(true);
    let t = std::time::Instant::now();
    let n = 50;
    for _ in 0..n {
        agent.update(&batch);
    }
    println!(
        "{:.2} ms/update",
        t.elapsed().as_secs_f64() * 1e3 / n as f64
    );
    println!("{:?}", agent.profile());
}
