//! The memory check of the learner: RDPG vs DDPG on Pendulum with the velocity hidden.
//!
//! `cargo run --release -p rdpg-agents --example pendulum_memory -- ALGO SEED STEPS`
//! (ALGO = rdpg | ddpg) prints one JSON line per evaluation (10 deterministic episodes on
//! held-out seeds) and a final summary line.

use rdpg_agents::train::{EpisodeRecord, EvalRecord, TrainConfig, TrainObserver, Trainer};
use rdpg_agents::{memory_task_config, set_num_threads};

struct Print;
impl TrainObserver for Print {
    fn on_episode(&mut self, _r: &EpisodeRecord) {}
    fn on_eval(&mut self, r: &EvalRecord) {
        println!(
            "{{\"step\":{},\"eval_mean\":{:.1},\"eval_std\":{:.1}}}",
            r.step, r.mean_return, r.std_return
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
    set_num_threads(1);
    let agent = memory_task_config(algo == "ddpg");
    let cfg = TrainConfig {
        total_steps: steps,
        seed,
        eval_every: 5_000,
        ..TrainConfig::default()
    };
    let t0 = std::time::Instant::now();
    let mut trainer = Trainer::new(cfg, agent)?;
    let mut best = f64::NEG_INFINITY;
    struct Best<'a>(&'a mut f64);
    impl TrainObserver for Best<'_> {
        fn on_eval(&mut self, r: &EvalRecord) {
            Print.on_eval(r);
            *self.0 = self.0.max(r.mean_return);
        }
    }
    trainer.run(steps, &mut Best(&mut best))?;
    let last = trainer.evaluate()?;
    println!(
        "{{\"algo\":\"{algo}\",\"seed\":{seed},\"steps\":{steps},\"final_eval_mean\":{:.1},\"best_eval_mean\":{:.1},\"seconds\":{:.1}}}",
        last.mean_return,
        best.max(last.mean_return),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
