//! Update throughput of the tch learner at BipedalWalker sizes (obs 24, act 4), the
//! counterpart of `scripts/bench/pytorch_update_bench.py`. Prints one JSON line.
//!
//! ```text
//! cargo run --release -p rdpg-agents --example bench_update -- \
//!     [--scan 24] [--batch 64] [--opt 8] [--iters 30] [--threads 2] [--short 0.0] \
//!     [--scan-method grouped|masked_loop] [--old-critic] [--bptt] [--tau 0.0] [--twin] \
//!     [--device cpu|cuda|auto]
//! ```

use rdpg_agents::rdpg::bench::bench_update_with;
use rdpg_agents::rdpg::ScanMethod;
use rdpg_agents::{DeviceSpec, RdpgConfig};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let get = |name: &str| -> Option<String> {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1).cloned())
    };
    let flag = |name: &str| args.iter().any(|a| a == name);
    let num = |name: &str, default: f64| -> f64 {
        get(name)
            .map(|v| v.parse().expect("number"))
            .unwrap_or(default)
    };
    let scan = num("--scan", 24.0) as usize;
    let batch = num("--batch", 64.0) as usize;
    let opt = num("--opt", 8.0) as usize;
    let iters = num("--iters", 30.0) as usize;
    let threads = num("--threads", 2.0) as usize;
    let short = num("--short", 0.0);
    let scan_method = match get("--scan-method").as_deref() {
        None | Some("grouped") => ScanMethod::Grouped,
        Some("masked_loop") => ScanMethod::MaskedLoop,
        Some(other) => panic!("unknown scan method {other}"),
    };
    let device = match get("--device").as_deref() {
        None | Some("cpu") => DeviceSpec::Cpu,
        Some("cuda") => DeviceSpec::Cuda,
        Some("auto") => DeviceSpec::Auto,
        Some(other) => panic!("unknown device {other}"),
    };
    let cfg = RdpgConfig {
        scan_len: scan,
        batch_size: batch,
        opt_len: opt,
        update_len: opt,
        scan_method,
        actor_uses_updated_critic: !flag("--old-critic"),
        actor_bptt: flag("--bptt"),
        tau: num("--tau", 0.0),
        twin_critic: flag("--twin"),
        device,
        num_threads: Some(threads),
        ..Default::default()
    };
    let r = bench_update_with(&cfg, 24, 4, short, iters).expect("bench");
    let p = r.per_update;
    let ms = |s: f64| (s * 1e4).round() / 10.0;
    println!(
        "{{\"impl\":\"tch\",\"device\":\"{device:?}\",\"threads\":{threads},\"batch\":{batch},\"scan\":{scan},\"opt\":{opt},\
         \"short\":{short},\"scan_method\":\"{scan_method:?}\",\"updated_critic\":{},\"bptt\":{},\"tau\":{},\"twin\":{},\
         \"updates_per_sec\":{:.2},\"ms\":{{\"prepare\":{},\"scan\":{},\"window_nograd\":{},\"critic_step\":{},\
         \"critic_rescan\":{},\"actor_step\":{},\"other\":{}}}}}",
        cfg.actor_uses_updated_critic,
        cfg.actor_bptt,
        cfg.tau,
        cfg.twin_critic,
        r.updates_per_sec,
        ms(p.prepare),
        ms(p.scan),
        ms(p.window_nograd),
        ms(p.critic_step),
        ms(p.critic_rescan),
        ms(p.actor_step),
        ms(p.other),
    );
}
