//! The on-policy PPO loop on the shared [`Collector`].
//!
//! Each iteration collects `rollout_steps` steps from each of the `N` environments with the
//! current policy (`a_t ~ pi_old(.|o_t)`; the unclipped sample is what the policy "did", the
//! environment receives it clipped to `[-1, 1]` and mapped to its bounds), then makes one
//! update phase ([`PpoAgent::update`]) on the GAE advantages (`gae::rollout_advantages`).

use std::path::Path;

use rdpg_core::rng::NpRng;
use serde::{Deserialize, Serialize};

use super::agent::{PpoAgent, PpoBatch, PpoStats};
use super::config::PpoConfig;
use super::gae::{rollout_advantages, Rollout};
use crate::common::checkpoint::{
    ckpt_err, read_bin, read_json, write_bin, write_json, Header, TrainerKind,
};
use crate::common::{evaluate_policy, Collector, EvalRecord, TrainConfig, TrainObserver, Trainer};
use crate::error::Result;

/// PPO's own loop state, saved with a checkpoint as `loop.bin` (the collector's is
/// `collector.bin`).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct LoopState {
    rng: NpRng,
    rollout: Rollout,
}

/// On-policy training of a [`PpoAgent`].
///
/// Everything random is seeded: the networks (`seed`), the environments (the collector's seed
/// schedule), the action noise and the minibatch shuffles (one [`NpRng`]). It resumes
/// bit-identically at any step, mid-rollout and mid-episode ([`PpoTrainer::load`]).
pub struct PpoTrainer {
    cfg: TrainConfig,
    agent: PpoAgent,
    collector: Collector,
    st: LoopState,
}

impl PpoTrainer {
    /// A fresh run (validates both configs).
    pub fn new(train: TrainConfig, cfg: PpoConfig) -> Result<Self> {
        train.validate()?;
        cfg.validate()?;
        // Before any tensor work, so that libtorch's worker threads inherit the mode.
        crate::common::tensor::set_flush_denormal(true);
        let collector = Collector::new(&train)?;
        let agent = PpoAgent::new(cfg, collector.obs_dim(), collector.act_dim(), train.seed)?;
        let st = LoopState {
            rng: NpRng::from_seed(train.seed ^ 0x9905_A11C_E5EE_D000),
            rollout: Rollout::default(),
        };
        Ok(Self {
            cfg: train,
            agent,
            collector,
            st,
        })
    }

    /// Resumes a checkpoint written by [`Trainer::save`]; continuing gives the same result as
    /// never having stopped. Episodes in progress are rebuilt from their seed and actions.
    pub fn load(dir: &Path) -> Result<Self> {
        Header::read(dir, Some(TrainerKind::Ppo))?;
        let cfg: TrainConfig = read_json(&dir.join("train.json"))?;
        cfg.validate()?;
        let agent = PpoAgent::load(dir.join("agent"))?;
        let st: LoopState = read_bin(&dir.join("loop.bin"))?;
        let collector = Collector::restore(&cfg, read_bin(&dir.join("collector.bin"))?)?;
        let n = cfg.num_envs;
        let (d, a) = (collector.obs_dim(), collector.act_dim());
        if (agent.obs_dim(), agent.act_dim()) != (d, a) {
            return Err(ckpt_err(
                &dir.join("agent"),
                format!(
                    "agent obs/act sizes {}/{} but the env has {d}/{a}",
                    agent.obs_dim(),
                    agent.act_dim()
                ),
            ));
        }
        let ro = &st.rollout;
        let m = ro.len * n;
        let consistent = ro.len < agent.config().rollout_steps
            && ro.obs.len() == m * d
            && ro.actions.len() == m * a
            && ro.rewards.len() == m
            && ro.terminated.len() == m
            && ro.ended.len() == m
            && ro
                .truncated_obs
                .iter()
                .all(|(k, o)| *k < m && ro.ended[*k] && o.len() == d);
        if !consistent {
            return Err(ckpt_err(
                &dir.join("loop.bin"),
                "loop state does not match num_envs, the env or rollout_steps",
            ));
        }
        Ok(Self {
            cfg,
            agent,
            collector,
            st,
        })
    }

    /// The agent being trained.
    pub fn agent(&self) -> &PpoAgent {
        &self.agent
    }

    /// The agent being trained, mutably.
    pub fn agent_mut(&mut self) -> &mut PpoAgent {
        &mut self.agent
    }

    /// Ends the current rollout: values, GAE, one PPO update phase; starts a new rollout.
    fn update_from_rollout(&mut self) -> Result<PpoStats> {
        let ro = std::mem::take(&mut self.st.rollout);
        let n = self.cfg.num_envs;
        let c = self.agent.config().clone();
        // V of the rollout's observations [len * n], of the next observations [n] and of the
        // truncated episodes' last observations [k], in one forward pass.
        let mut all = ro.obs.clone();
        all.extend(self.collector.obs().concat());
        for (_, o) in &ro.truncated_obs {
            all.extend_from_slice(o);
        }
        let v: Vec<f64> = self.agent.values(&all).into_iter().map(f64::from).collect();
        let m = ro.len * n;
        let (values, rest) = v.split_at(m);
        let (last_values, trunc_values) = rest.split_at(n);
        let adv = rollout_advantages(
            &ro,
            n,
            values,
            last_values,
            trunc_values,
            c.gamma,
            c.gae_lambda,
        );
        let batch = PpoBatch {
            returns: adv
                .iter()
                .zip(values)
                .map(|(a, v)| (a + v) as f32)
                .collect(),
            advantages: adv.iter().map(|&a| a as f32).collect(),
            obs: ro.obs,
            actions: ro.actions,
        };
        self.agent.update(&batch, &mut self.st.rng)
    }
}

impl Trainer for PpoTrainer {
    /// A rollout cut short here is kept and continued by the next call.
    fn run(&mut self, until: u64, cb: &mut dyn TrainObserver) -> Result<u64> {
        // Acting and updating share this thread; flush denormals for both, so that a resumed
        // run acts under the same floating-point mode as an uninterrupted one.
        crate::common::tensor::set_flush_denormal(true);
        let until = until.min(self.cfg.total_steps);
        let a_dim = self.agent.act_dim();
        let n = self.cfg.num_envs;
        while self.collector.steps() < until {
            if cb.should_stop(self.collector.steps()) {
                break;
            }
            // Acting: a_t ~ N(mu(o_t), sigma^2) per env; the env gets clip(a_t, -1, 1) mapped
            // to its bounds.
            let flat: Vec<f32> = self.collector.obs().concat(); // [n, D]
            let raw = self.agent.sample(&flat, &mut self.st.rng); // [n, A]
            let actions: Vec<Vec<f32>> = raw.chunks(a_dim).map(<[f32]>::to_vec).collect();
            let transitions = self.collector.step(&actions)?;
            let ro = &mut self.st.rollout;
            let t = ro.len;
            ro.obs.extend_from_slice(&flat);
            ro.actions.extend_from_slice(&raw);
            for (i, tr) in transitions.into_iter().enumerate() {
                let s = tr.step;
                ro.rewards.push(s.reward);
                ro.terminated.push(s.terminated);
                ro.ended.push(s.final_obs.is_some());
                if let Some(last) = s.final_obs {
                    if !s.terminated {
                        ro.truncated_obs.push((t * n + i, last));
                    }
                }
                if let Some(rec) = tr.finished {
                    cb.on_episode(&rec);
                }
            }
            ro.len += 1;
            if self.st.rollout.len >= self.agent.config().rollout_steps {
                let stats = self.update_from_rollout()?;
                cb.on_update(self.collector.steps(), &stats.into());
            }
            if self.collector.eval_due() {
                let rec = self.evaluate()?;
                cb.on_eval(&rec);
            }
        }
        Ok(self.collector.steps())
    }

    /// The policy mean, clamped, on the held-out seeds.
    fn evaluate(&mut self) -> Result<EvalRecord> {
        let (episodes, seed) = (self.cfg.eval_episodes, self.cfg.eval_seed);
        let mut rec = evaluate_policy(&mut self.agent, &self.cfg, episodes, seed)?;
        rec.step = self.collector.steps();
        Ok(rec)
    }

    /// The agent (`agent/`: networks, optimiser moments, beta), PPO's loop state
    /// (`loop.bin`: generator, partial rollout), the collector (`collector.bin`) and the run
    /// config (`train.json`).
    fn save(&mut self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| ckpt_err(dir, e))?;
        Header::write(dir, TrainerKind::Ppo)?;
        self.agent.save(dir.join("agent"))?;
        write_bin(&dir.join("loop.bin"), &self.st)?;
        write_bin(&dir.join("collector.bin"), self.collector.state())?;
        write_json(&dir.join("train.json"), &self.cfg)?;
        crate::common::checkpoint::seal(dir)
    }

    fn save_agent(&self, dir: &Path) -> Result<()> {
        self.agent.save(dir)
    }

    fn steps(&self) -> u64 {
        self.collector.steps()
    }

    fn updates(&self) -> u64 {
        self.agent.updates()
    }

    fn set_total_steps(&mut self, total: u64) {
        self.cfg.total_steps = total;
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn config(&self) -> &TrainConfig {
        &self.cfg
    }
}
