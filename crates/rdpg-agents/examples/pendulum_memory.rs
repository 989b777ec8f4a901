//! The memory check of the learner: RDPG vs DDPG on Pendulum with the velocity hidden.
//!
//! `cargo run --release -p rdpg-agents --example pendulum_memory -- ALGO SEED STEPS [UPS]`
//! (ALGO = rdpg | ddpg, UPS = updates per env step, default 0.25) prints one JSON line per
//! evaluation (10 deterministic episodes on held-out seeds) and a final summary line. `RDPG_PROFILE=1` adds the per-phase split.

use rdpg_agents::train::{EvalRecord, TrainConfig, TrainObserver, Trainer};
use rdpg_agents::{memory_task_config, set_num_threads};
use std::time::Instant;

struct Print {
    best: f64,
    t0: Instant,
}
impl TrainObserver for Print {
    fn on_eval(&mut self, r: &EvalRecord) {
        self.best = self.best.max(r.mean_return);
        println!(
            "{{\"step\":{},\"eval_mean\":{:.1},\"eval_std\":{:.1},\"seconds\":{:.1}}}",
            r.step,
            r.mean_return,
            r.std_return,
            self.t0.elapsed().as_secs_f64()
        );
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let algo = args.get(1).map(String::as_str).unwrap_or("rdpg");
    let seed: u64 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(0);
    let steps: u64 = args
        .get(3)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(50_000);
    let ups: f64 = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(0.25);
    set_num_threads(1);
    let agent = memory_task_config(algo == "ddpg");
    let cfg = TrainConfig {
        total_steps: steps,
        seed,
        eval_every: 5_000,
        updates_per_step: ups,
        ..TrainConfig::default()
    };
    let t0 = Instant::now();
    let mut trainer = Trainer::new(cfg, agent)?;
    trainer
        .agent_mut()
        .set_profiling(std::env::var_os("RDPG_PROFILE").is_some());
    let mut obs = Print {
        best: f64::NEG_INFINITY,
        t0,
    };
    trainer.run(steps, &mut obs)?;
    let train_secs = t0.elapsed().as_secs_f64();
    let last = trainer.evaluate()?;
    if let Some(p) = trainer.agent().profile() {
        eprintln!("profile: {p:?}");
    }
    println!(
        "{{\"algo\":\"{algo}\",\"seed\":{seed},\"steps\":{steps},\"ups\":{ups},\"updates\":{},\"final_eval_mean\":{:.1},\"best_eval_mean\":{:.1},\"train_seconds\":{:.1}}}",
        trainer.agent().updates(),
        last.mean_return,
        obs.best.max(last.mean_return),
        train_secs
    );
    Ok(())
}
