//! The off-policy training loop shared by RDPG and DDPG (Algorithm 1's outer loop).
//!
//! Acting runs on a [`VecEnv`] (N environments on worker threads) with batched policy
//! inference; every environment keeps its own recurrent actor state and exploration noise.
//! Each finished episode goes to the [`EpisodicReplay`] whole, and after the warm-up the agent
//! makes `updates_per_step` updates per environment step on windows sampled from it.
//!
//! Everything random is seeded: the networks (`seed`), the environments (a seed schedule, one
//! seed per episode, see [`rdpg_envs::vector::episode_seed`]), warm-up actions, noise and
//! replay sampling (one [`NpRng`]). A [`Trainer`] can be checkpointed at any step
//! ([`Trainer::save`]) and resumed ([`Trainer::load`]) bit-identically: episodes in progress
//! are rebuilt from their seed and actions.

use std::borrow::BorrowMut;
use std::path::Path;

use rdpg_core::noise::{
    action_distance, ActionNoise, AdaptiveParamNoise, Gaussian, OrnsteinUhlenbeck, OuConfig,
    ParamNoiseConfig,
};
use rdpg_core::replay::{Episode, EpisodicReplay, ReplayConfig};
use rdpg_core::rng::NpRng;
use rdpg_envs::{EnvOptions, VecEnv, WalkerReward};
use serde::{Deserialize, Serialize};

use crate::inject::{InjectionConfig, TeacherFile};
use crate::{ActorState, AgentError, RdpgAgent, RdpgConfig, Result, UpdateStats};

/// Exploration noise added to the deterministic policy's actions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ExplorationConfig {
    /// No noise.
    None,
    /// Ornstein–Uhlenbeck noise, reset at every episode start.
    Ou {
        /// Mean-reversion rate θ.
        theta: f64,
        /// Scale σ.
        sigma: f64,
    },
    /// Independent Gaussian noise of standard deviation `sigma`.
    Gaussian {
        /// Standard deviation.
        sigma: f64,
    },
}

impl Default for ExplorationConfig {
    fn default() -> Self {
        Self::Ou {
            theta: 0.15,
            sigma: 0.2,
        }
    }
}

/// Adaptive parameter-space noise on the actor (paper Sec. II-B and Algorithm 1's `Noise()` /
/// `Denoise()`; Plappert et al. 2018), on top of the action noise.
///
/// Every `every_steps` environment steps after the warm-up, the trainer measures how far the
/// perturbed actor's actions are from the trained actor's on observations sampled from the
/// replay (zero recurrent state), adapts σ towards `desired_action_stddev`, and perturbs a fresh
/// copy of the trained actor with `N(0, σ²)` on every parameter. The environments act with that
/// copy; updates always train the unperturbed actor (the "denoise before Update()" of
/// Algorithm 1), and evaluations use it too.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamNoiseSpec {
    /// Initial σ of the parameter perturbation.
    pub initial_stddev: f64,
    /// Target RMS distance between perturbed and unperturbed actions (in `[-1, 1]` units).
    pub desired_action_stddev: f64,
    /// Multiplicative step of σ's adaptation (`> 1`).
    pub adoption_coefficient: f64,
    /// Environment steps (over all environments) between perturbations.
    pub every_steps: u64,
}

impl Default for ParamNoiseSpec {
    fn default() -> Self {
        let c = ParamNoiseConfig::default();
        Self {
            initial_stddev: c.initial_stddev,
            desired_action_stddev: c.desired_action_stddev,
            adoption_coefficient: c.adoption_coefficient,
            every_steps: 1000,
        }
    }
}

/// Everything about a training run except the learner's own hyper-parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Environment id (see `rdpg_envs::ENV_IDS`).
    pub env: String,
    /// Observation components hidden from the agent (indices into the env's observation).
    pub hide_obs: Vec<usize>,
    /// Walkers: reward used for learning (`stock` or `paper`); evaluation always reports the
    /// stock return.
    pub reward: WalkerReward,
    /// Budget in environment steps (over all environments).
    pub total_steps: u64,
    /// Steps of uniform random actions before the first update.
    pub warmup_steps: u64,
    /// Gradient updates per environment step (fractional values accumulate).
    pub updates_per_step: f64,
    /// Environments acting in parallel.
    pub num_envs: usize,
    /// Worker threads stepping them.
    pub workers: usize,
    /// Replay capacity in transitions (whole episodes are evicted oldest first).
    pub replay_capacity: usize,
    /// Exploration noise on the actions.
    pub exploration: ExplorationConfig,
    /// Parameter-space noise on the actor, in addition to `exploration`; none when absent.
    pub param_noise: Option<ParamNoiseSpec>,
    /// Experience injection from teacher files (paper Sec. III-D); none when absent.
    pub injection: Option<InjectionConfig>,
    /// Evaluate every this many environment steps (0: only at the end).
    pub eval_every: u64,
    /// Deterministic evaluation episodes.
    pub eval_episodes: usize,
    /// First seed of the held-out evaluation episodes (episode k uses `eval_seed + k`).
    pub eval_seed: u64,
    /// Master seed of the run.
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            env: "PendulumNoVel-v1".into(),
            hide_obs: Vec::new(),
            reward: WalkerReward::Stock,
            total_steps: 50_000,
            warmup_steps: 2_000,
            updates_per_step: 1.0,
            num_envs: 1,
            workers: 1,
            replay_capacity: 100_000,
            exploration: ExplorationConfig::default(),
            param_noise: None,
            injection: None,
            eval_every: 5_000,
            eval_episodes: 10,
            eval_seed: 1_000_000,
            seed: 0,
        }
    }
}

impl TrainConfig {
    /// Checks every field; the error names the offending one.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, reason: String| Err(AgentError::Config { field, reason });
        if !rdpg_envs::ENV_IDS.contains(&self.env.as_str()) {
            return bad(
                "train.env",
                format!(
                    "unknown id {:?} (known: {})",
                    self.env,
                    rdpg_envs::ENV_IDS.join(", ")
                ),
            );
        }
        if self.total_steps == 0 {
            return bad("train.total_steps", "must be positive".into());
        }
        if !(self.updates_per_step.is_finite() && self.updates_per_step >= 0.0) {
            return bad(
                "train.updates_per_step",
                format!("{} is not a non-negative number", self.updates_per_step),
            );
        }
        if self.num_envs == 0 {
            return bad("train.num_envs", "must be at least 1".into());
        }
        if self.workers == 0 {
            return bad("train.workers", "must be at least 1".into());
        }
        if self.replay_capacity == 0 {
            return bad("train.replay_capacity", "must be positive".into());
        }
        if self.eval_episodes == 0 {
            return bad("train.eval_episodes", "must be at least 1".into());
        }
        if let Some(inj) = &self.injection {
            inj.validate()?;
        }
        if let Some(p) = &self.param_noise {
            let ok = p.initial_stddev.is_finite()
                && p.initial_stddev > 0.0
                && p.desired_action_stddev.is_finite()
                && p.desired_action_stddev > 0.0
                && p.adoption_coefficient.is_finite()
                && p.adoption_coefficient > 1.0
                && p.every_steps > 0;
            if !ok {
                return bad(
                    "train.param_noise",
                    format!(
                        "needs initial_stddev > 0, desired_action_stddev > 0, \
                         adoption_coefficient > 1 and every_steps > 0 (got {p:?})"
                    ),
                );
            }
        }
        match self.exploration {
            ExplorationConfig::Ou { theta, sigma }
                if theta.is_nan() || sigma.is_nan() || theta <= 0.0 || sigma < 0.0 =>
            {
                bad(
                    "train.exploration",
                    format!("OU needs theta > 0 and sigma >= 0 (got {theta}, {sigma})"),
                )
            }
            ExplorationConfig::Gaussian { sigma } if sigma.is_nan() || sigma < 0.0 => bad(
                "train.exploration",
                format!("Gaussian needs sigma >= 0 (got {sigma})"),
            ),
            _ => Ok(()),
        }
    }

    /// The vector env of the run and the action bounds of its environments.
    pub(crate) fn make_envs(&self) -> Result<(VecEnv, Vec<f32>, Vec<f32>)> {
        let probe = rdpg_envs::make_with(&self.env, &self.env_options())?;
        let space = probe.action_space();
        let venv = VecEnv::make(&self.env, &self.env_options(), self.num_envs, self.workers)?;
        Ok((venv, space.low.clone(), space.high.clone()))
    }

    /// The environment options of the run's training environments.
    pub fn env_options(&self) -> EnvOptions {
        EnvOptions {
            reward: self.reward,
            hide_obs: self.hide_obs.clone(),
            max_episode_steps: None,
        }
    }
}

/// A finished training episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeRecord {
    /// Environment steps taken by the run when the episode ended.
    pub step: u64,
    /// Which environment of the vector env.
    pub env: usize,
    /// Sum of the training reward (with exploration noise).
    pub ret: f64,
    /// Sum of the stock reward (equals `ret` unless training on another reward).
    pub stock_return: f64,
    /// Length in steps.
    pub len: usize,
    /// Reached the end of the course without falling (walkers).
    pub success: bool,
}

/// A deterministic evaluation on held-out seeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalRecord {
    /// Environment steps of the run at evaluation time.
    pub step: u64,
    /// Mean stock return.
    pub mean_return: f64,
    /// Standard deviation of the stock return.
    pub std_return: f64,
    /// Share of episodes that reached the end of the course.
    pub success_rate: f64,
    /// Every episode's stock return.
    pub returns: Vec<f64>,
}

/// Receives progress from [`Trainer::run`] (metrics files, progress bars, tests).
pub trait TrainObserver {
    /// An episode finished.
    fn on_episode(&mut self, _rec: &EpisodeRecord) {}
    /// An evaluation finished.
    fn on_eval(&mut self, _rec: &EvalRecord) {}
    /// An update was made at environment step `step`.
    fn on_update(&mut self, _step: u64, _stats: &UpdateStats) {}
    /// Called every environment step; return `true` to stop (e.g. Ctrl-C, to save first).
    fn should_stop(&mut self, _step: u64) -> bool {
        false
    }
}

/// An observer that ignores everything.
pub struct Quiet;
impl TrainObserver for Quiet {}

/// The transitions of an episode in progress.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct OpenEpisode {
    obs: Vec<f32>,
    /// Actions in the agent's normalised `[-1, 1]` space (what the replay stores).
    actions: Vec<f32>,
    /// Actions as sent to the env (for rebuilding the episode on resume).
    env_actions: Vec<Vec<f32>>,
    rewards: Vec<f32>,
    states: Vec<f32>,
    ret: f64,
    stock_ret: f64,
}

/// Counters and generators saved with a checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct LoopState {
    steps: u64,
    update_debt: f64,
    rng: NpRng,
    noise: Vec<ActionNoise>,
    open: Vec<OpenEpisode>,
    episode_index: Vec<u64>,
    actor_state: Vec<f32>,
    next_eval: u64,
    param_noise: Option<ParamNoiseState>,
}

/// The parameter noise of a run: σ, the perturbed parameters the envs act with (empty before
/// the first perturbation) and when to perturb next.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct ParamNoiseState {
    noise: AdaptiveParamNoise,
    acting: Vec<f32>,
    next_perturb: u64,
}

/// Off-policy training of an [`RdpgAgent`] (recurrent RDPG or feed-forward DDPG).
pub struct Trainer {
    cfg: TrainConfig,
    agent: RdpgAgent,
    replay: EpisodicReplay,
    venv: VecEnv,
    obs: Vec<Vec<f32>>,
    act_state: ActorState,
    low: Vec<f32>,
    high: Vec<f32>,
    st: LoopState,
}

impl Trainer {
    /// A fresh run.
    pub fn new(cfg: TrainConfig, agent_cfg: RdpgConfig) -> Result<Self> {
        cfg.validate()?;
        let (mut venv, low, high) = cfg.make_envs()?;
        let (obs_dim, act_dim) = (venv.obs_dim(), venv.act_dim());
        let agent = RdpgAgent::new(agent_cfg, obs_dim, act_dim, cfg.seed)?;
        let obs = venv.reset_scheduled(cfg.seed, &vec![0; cfg.num_envs])?;
        let state_dim = if agent.config().burn_in_from_stored_state {
            agent.state_dim()
        } else {
            0
        };
        let mut rcfg =
            ReplayConfig::new(cfg.replay_capacity, obs_dim, act_dim).with_state_dim(state_dim);
        if let Some(inj) = &cfg.injection {
            rcfg = rcfg.with_max_injected_fraction(inj.max_fraction);
        }
        let mut replay = EpisodicReplay::new(rcfg).map_err(|e| AgentError::Config {
            field: "replay",
            reason: e.to_string(),
        })?;
        for path in cfg.injection.iter().flat_map(|i| &i.teachers) {
            let teacher = TeacherFile::load(path)?;
            teacher.check_fits(&cfg, path)?;
            if (teacher.obs_dim, teacher.act_dim) != (obs_dim, act_dim) {
                return Err(AgentError::Config {
                    field: "train.injection",
                    reason: format!(
                        "teacher {} has obs/act sizes {}/{}, the env {obs_dim}/{act_dim}",
                        path.display(),
                        teacher.obs_dim,
                        teacher.act_dim
                    ),
                });
            }
            for mut ep in teacher.episodes {
                ep.injected = true;
                replay.add_episode(ep).map_err(|e| AgentError::Config {
                    field: "train.injection",
                    reason: format!("teacher {}: {e}", path.display()),
                })?;
            }
        }
        let noise = (0..cfg.num_envs)
            .map(|_| make_noise(&cfg.exploration, act_dim))
            .collect();
        let open = obs
            .iter()
            .map(|o| OpenEpisode {
                obs: o.clone(),
                ..Default::default()
            })
            .collect();
        let act_state = agent.initial_state(cfg.num_envs);
        let st = LoopState {
            steps: 0,
            update_debt: 0.0,
            rng: NpRng::from_seed(cfg.seed ^ 0x5EED_F07E_A1A1),
            noise,
            open,
            episode_index: vec![0; cfg.num_envs],
            actor_state: Vec::new(),
            next_eval: if cfg.eval_every > 0 {
                cfg.eval_every
            } else {
                u64::MAX
            },
            param_noise: cfg.param_noise.map(|p| ParamNoiseState {
                noise: AdaptiveParamNoise::new(ParamNoiseConfig {
                    initial_stddev: p.initial_stddev,
                    desired_action_stddev: p.desired_action_stddev,
                    adoption_coefficient: p.adoption_coefficient,
                }),
                acting: Vec::new(),
                next_perturb: 0,
            }),
        };
        Ok(Self {
            cfg,
            agent,
            replay,
            venv,
            obs,
            act_state,
            low,
            high,
            st,
        })
    }

    /// The agent being trained.
    pub fn agent(&self) -> &RdpgAgent {
        &self.agent
    }

    /// The agent being trained, mutably (e.g. to switch on [`RdpgAgent::set_profiling`]).
    pub fn agent_mut(&mut self) -> &mut RdpgAgent {
        &mut self.agent
    }

    /// The run's configuration.
    pub fn config(&self) -> &TrainConfig {
        &self.cfg
    }

    /// Environment steps taken so far.
    pub fn steps(&self) -> u64 {
        self.st.steps
    }

    /// The replay buffer.
    pub fn replay(&self) -> &EpisodicReplay {
        &self.replay
    }

    fn to_env_action(&self, a: &[f32]) -> Vec<f32> {
        to_env_action(a, &self.low, &self.high)
    }

    /// Runs until `until` environment steps (capped by the budget) or until the observer asks
    /// to stop. Returns the step count reached.
    pub fn run(&mut self, until: u64, obs_cb: &mut dyn TrainObserver) -> Result<u64> {
        let until = until.min(self.cfg.total_steps);
        let n = self.cfg.num_envs;
        let act_dim = self.agent.act_dim();
        let stored = self.replay.config().state_dim > 0;
        while self.st.steps < until {
            if obs_cb.should_stop(self.st.steps) {
                break;
            }
            // Acting: a_t = mu(o_t, h_{t-1}) + N_t (Algorithm 1), uniform during warm-up.
            let states: Vec<Vec<f32>> = if stored {
                (0..n).map(|i| self.act_state.env_state(i)).collect()
            } else {
                vec![Vec::new(); n]
            };
            let warm = self.st.steps < self.cfg.warmup_steps;
            if !warm {
                self.perturb_actor_if_due()?;
            }
            let flat: Vec<f32> = self.obs.concat();
            let mu = self.agent.act(&flat, &mut self.act_state);
            let actions: Vec<Vec<f32>> = (0..n)
                .map(|i| {
                    if warm {
                        (0..act_dim)
                            .map(|_| self.st.rng.uniform(-1.0, 1.0) as f32)
                            .collect()
                    } else {
                        let eps = self.st.noise[i].sample(&mut self.st.rng);
                        mu[i * act_dim..(i + 1) * act_dim]
                            .iter()
                            .zip(eps)
                            .map(|(m, e)| (m + e).clamp(-1.0, 1.0))
                            .collect()
                    }
                })
                .collect();
            let env_actions: Vec<Vec<f32>> =
                actions.iter().map(|a| self.to_env_action(a)).collect();
            let steps = self.venv.step(&env_actions)?;
            self.st.steps += n as u64;
            for (i, s) in steps.into_iter().enumerate() {
                let ep = &mut self.st.open[i];
                let next = s.final_obs.as_ref().unwrap_or(&s.obs);
                ep.obs.extend_from_slice(next);
                ep.actions.extend_from_slice(&actions[i]);
                ep.env_actions.push(env_actions[i].clone());
                ep.rewards.push(s.reward as f32);
                ep.states.extend_from_slice(&states[i]);
                ep.ret += s.reward;
                ep.stock_ret += s.info.stock_reward.unwrap_or(s.reward);
                if s.final_obs.is_some() {
                    let done = std::mem::replace(
                        ep,
                        OpenEpisode {
                            obs: s.obs.clone(),
                            ..Default::default()
                        },
                    );
                    let rec = EpisodeRecord {
                        step: self.st.steps,
                        env: i,
                        ret: done.ret,
                        stock_return: done.stock_ret,
                        len: done.rewards.len(),
                        success: s.info.success,
                    };
                    self.replay
                        .add_episode(Episode {
                            obs: done.obs,
                            actions: done.actions,
                            rewards: done.rewards,
                            states: done.states,
                            terminated: s.terminated,
                            truncated: s.truncated && !s.terminated,
                            injected: false,
                        })
                        .map_err(|e| AgentError::Config {
                            field: "replay",
                            reason: e.to_string(),
                        })?;
                    self.agent.reset_state(&mut self.act_state, Some(i));
                    self.st.noise[i].reset();
                    obs_cb.on_episode(&rec);
                }
                self.obs[i] = s.obs;
            }
            self.st.episode_index = self.venv.episode_indices();
            // Learning: Update() of Algorithm 1 on sampled sub-trajectories.
            if !warm && self.replay.num_episodes() > 0 {
                self.st.update_debt += self.cfg.updates_per_step * n as f64;
                let c = self.agent.config();
                let (b, s, l) = (c.batch_size, c.scan_len, c.opt_len);
                while self.st.update_debt >= 1.0 {
                    self.st.update_debt -= 1.0;
                    let rng = &mut self.st.rng;
                    let sampled = match &self.cfg.injection {
                        // A share of the windows from teacher episodes, annealed to 0.
                        Some(inj) => {
                            let share = inj.share(self.st.steps);
                            self.replay.sample_mixed(rng, b, s, l, share)
                        }
                        None => self.replay.sample(rng, b, s, l),
                    };
                    let Some(batch) = sampled else {
                        break;
                    };
                    let stats = self.agent.update(&batch);
                    obs_cb.on_update(self.st.steps, &stats);
                }
            }
            if self.st.steps >= self.st.next_eval {
                let rec = self.evaluate()?;
                obs_cb.on_eval(&rec);
                self.st.next_eval = self.st.next_eval.saturating_add(self.cfg.eval_every);
            }
        }
        Ok(self.st.steps)
    }

    /// Algorithm 1's `Noise()`: when due, adapts σ to the distance the current perturbation
    /// makes and acts from now on with a freshly perturbed copy of the trained actor.
    fn perturb_actor_if_due(&mut self) -> Result<()> {
        let Some(pn) = self.st.param_noise.as_mut() else {
            return Ok(());
        };
        if self.st.steps < pn.next_perturb {
            return Ok(());
        }
        if !pn.acting.is_empty() {
            if let Some(b) = self.replay.sample(&mut self.st.rng, 64, 0, 1) {
                // obs [n, 2, obs_dim]: the first step of each window.
                let d = b.obs_dim;
                let obs: Vec<f32> = (0..b.n)
                    .flat_map(|i| b.obs[i * 2 * d..i * 2 * d + d].iter().copied())
                    .collect();
                let perturbed = self.agent.act(&obs, &mut self.agent.initial_state(b.n));
                let clean = self
                    .agent
                    .act_unperturbed(&obs, &mut self.agent.initial_state(b.n));
                pn.noise.adapt(action_distance(&perturbed, &clean));
            }
        }
        let mut params = self.agent.actor_params();
        pn.noise.perturb(&mut params, &mut self.st.rng);
        self.agent.set_acting_params(Some(&params))?;
        pn.acting = params;
        pn.next_perturb = self.st.steps + self.cfg.param_noise.map_or(1, |p| p.every_steps);
        Ok(())
    }

    /// σ of the parameter noise (`None` without parameter noise).
    pub fn param_noise_stddev(&self) -> Option<f64> {
        self.st.param_noise.as_ref().map(|p| p.noise.sigma)
    }

    /// Deterministic evaluation (no noise) on the held-out seeds `eval_seed..`, on the stock
    /// reward, with a fresh recurrent state per episode (see [`evaluate_agent`]).
    pub fn evaluate(&mut self) -> Result<EvalRecord> {
        let (episodes, seed) = (self.cfg.eval_episodes, self.cfg.eval_seed);
        let mut rec = evaluate_agent(&mut self.agent, &self.cfg, episodes, seed)?;
        rec.step = self.st.steps;
        Ok(rec)
    }

    /// Raises (or lowers) the budget in environment steps, e.g. to continue a finished run.
    pub fn set_total_steps(&mut self, total: u64) {
        self.cfg.total_steps = total;
    }

    /// Writes a checkpoint to `dir`: the agent (networks, optimiser moments), the replay
    /// buffer, generators, noise, episodes in progress and counters.
    pub fn save(&mut self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir)?;
        self.agent.save(dir.join("agent"))?;
        self.st.actor_state = self.act_state.to_vec();
        write_bin(&dir.join("replay.bin"), &self.replay)?;
        write_bin(&dir.join("loop.bin"), &self.st)?;
        std::fs::write(
            dir.join("train.json"),
            serde_json::to_string_pretty(&self.cfg)?,
        )?;
        Ok(())
    }

    /// Resumes a checkpoint written by [`Trainer::save`]; continuing gives the same result as
    /// never having stopped.
    pub fn load(dir: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(dir.join("train.json")).map_err(|e| {
            AgentError::Checkpoint(format!("{}: {e}", dir.join("train.json").display()))
        })?;
        let cfg: TrainConfig = serde_json::from_str(&text).map_err(|e| {
            AgentError::Checkpoint(format!("{}: {e}", dir.join("train.json").display()))
        })?;
        cfg.validate()?;
        let agent = RdpgAgent::load(dir.join("agent"))?;
        let replay: EpisodicReplay = read_bin(&dir.join("replay.bin"))?;
        let st: LoopState = read_bin(&dir.join("loop.bin"))?;
        let n = cfg.num_envs;
        if st.open.len() != n || st.noise.len() != n || st.episode_index.len() != n {
            return Err(AgentError::Checkpoint(
                "loop state does not match num_envs".into(),
            ));
        }
        let (mut venv, low, high) = cfg.make_envs()?;
        venv.reset_scheduled(cfg.seed, &st.episode_index)?;
        let mut obs = Vec::with_capacity(n);
        for (i, ep) in st.open.iter().enumerate() {
            let o = venv.restore(i, ep.env_actions.clone())?;
            let dim = o.len();
            if ep.obs.len() < dim || ep.obs[ep.obs.len() - dim..] != o[..] {
                return Err(AgentError::Checkpoint(format!(
                    "env {i}: rebuilt episode differs from the checkpoint (different environment build?)"
                )));
            }
            obs.push(o);
        }
        let mut agent = agent;
        if let Some(pn) = st.param_noise.as_ref().filter(|p| !p.acting.is_empty()) {
            agent
                .set_acting_params(Some(&pn.acting))
                .map_err(|e| AgentError::Checkpoint(format!("parameter noise: {e}")))?;
        }
        if st.param_noise.is_some() != cfg.param_noise.is_some() {
            return Err(AgentError::Checkpoint(
                "parameter noise state does not match the config".into(),
            ));
        }
        let mut act_state = agent.initial_state(n);
        let sd = agent.state_dim();
        if st.actor_state.len() != n * sd {
            return Err(AgentError::Checkpoint(
                "actor state size does not match".into(),
            ));
        }
        for i in 0..n {
            if sd > 0 {
                act_state.set_env_state(i, &st.actor_state[i * sd..(i + 1) * sd]);
            }
        }
        Ok(Self {
            cfg,
            agent,
            replay,
            venv,
            obs,
            act_state,
            low,
            high,
            st,
        })
    }
}

/// A trained policy acting deterministically on one environment (evaluation, recording,
/// rendering), whatever the algorithm.
pub trait DeterministicPolicy {
    /// Starts a new episode (e.g. zeroes the recurrent state).
    fn begin_episode(&mut self);
    /// The action in `[-1, 1]^act_dim` for one observation.
    fn act(&mut self, obs: &[f32]) -> Vec<f32>;
}

/// An [`RdpgAgent`] (owned or borrowed) as a [`DeterministicPolicy`]: the unperturbed actor
/// with its own recurrent state.
pub struct RdpgPolicy<A> {
    agent: A,
    state: ActorState,
}

impl<A: BorrowMut<RdpgAgent>> RdpgPolicy<A> {
    /// Wraps `agent` (`RdpgAgent` or `&mut RdpgAgent`).
    pub fn new(agent: A) -> Self {
        let state = agent.borrow().initial_state(1);
        Self { agent, state }
    }
}

impl<A: BorrowMut<RdpgAgent>> DeterministicPolicy for RdpgPolicy<A> {
    fn begin_episode(&mut self) {
        self.state = self.agent.borrow().initial_state(1);
    }
    fn act(&mut self, obs: &[f32]) -> Vec<f32> {
        self.agent
            .borrow_mut()
            .act_unperturbed(obs, &mut self.state)
    }
}

/// Deterministic evaluation of `policy` on `episodes` episodes of `cfg`'s environment (its
/// observation mask included) with seeds `seed, seed + 1, ...`, scored on the stock reward,
/// each episode from a fresh state. `step` of the record is 0.
pub fn evaluate_policy(
    policy: &mut dyn DeterministicPolicy,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
) -> Result<EvalRecord> {
    let opts = EnvOptions {
        reward: WalkerReward::Stock,
        ..cfg.env_options()
    };
    let mut env = rdpg_envs::make_with(&cfg.env, &opts)?;
    let space = env.action_space().clone();
    let mut returns = Vec::with_capacity(episodes);
    let mut successes = 0;
    for k in 0..episodes {
        let (mut obs, _) = env.reset(Some(seed + k as u64))?;
        policy.begin_episode();
        let mut ret = 0.0;
        loop {
            let a = policy.act(&obs);
            let s = env.step(&to_env_action(&a, &space.low, &space.high))?;
            ret += s.reward;
            if s.done() {
                successes += s.info.success as usize;
                break;
            }
            obs = s.obs;
        }
        returns.push(ret);
    }
    let m = returns.len().max(1) as f64;
    let mean = returns.iter().sum::<f64>() / m;
    let std = (returns.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / m).sqrt();
    Ok(EvalRecord {
        step: 0,
        mean_return: mean,
        std_return: std,
        success_rate: successes as f64 / m,
        returns,
    })
}

/// [`evaluate_policy`] for an [`RdpgAgent`] (its unperturbed actor).
pub fn evaluate_agent(
    agent: &mut RdpgAgent,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
) -> Result<EvalRecord> {
    evaluate_policy(&mut RdpgPolicy::new(agent), cfg, episodes, seed)
}

/// Maps an action in the agent's `[-1, 1]` space to the env's bounds (clipping first).
pub fn to_env_action(a: &[f32], low: &[f32], high: &[f32]) -> Vec<f32> {
    a.iter()
        .zip(low.iter().zip(high))
        .map(|(&x, (&lo, &hi))| lo + (x.clamp(-1.0, 1.0) + 1.0) * 0.5 * (hi - lo))
        .collect()
}

fn make_noise(cfg: &ExplorationConfig, dim: usize) -> ActionNoise {
    match *cfg {
        ExplorationConfig::None => ActionNoise::None { dim },
        ExplorationConfig::Ou { theta, sigma } => ActionNoise::Ou(OrnsteinUhlenbeck::new(
            dim,
            OuConfig {
                theta,
                sigma,
                ..OuConfig::default()
            },
        )),
        ExplorationConfig::Gaussian { sigma } => ActionNoise::Gaussian(Gaussian::new(dim, sigma)),
    }
}

/// Writes `value` with bincode (checkpoint files).
pub(crate) fn write_bin<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let file = std::fs::File::create(path)?;
    bincode::serialize_into(std::io::BufWriter::new(file), value)
        .map_err(|e| AgentError::Checkpoint(format!("{}: {e}", path.display())))
}

/// Reads a file written by [`write_bin`]; a missing, truncated or corrupt file is a
/// checkpoint error naming it.
pub(crate) fn read_bin<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let file = std::fs::File::open(path)
        .map_err(|e| AgentError::Checkpoint(format!("{}: {e}", path.display())))?;
    bincode::deserialize_from(std::io::BufReader::new(file)).map_err(|e| {
        AgentError::Checkpoint(format!("{} is truncated or corrupt: {e}", path.display()))
    })
}

/// The learner configuration of the memory task (PendulumNoVel-v1): a small MLP trunk, LSTM 64
/// (or, with `ddpg`, the same network with the LSTM replaced by FC and `l = u = 1`, `s = 0`),
/// target networks with τ = 0.005, batch 64, `l = u = 8`, `s = 16`.
pub fn memory_task_config(ddpg: bool) -> RdpgConfig {
    let cfg = RdpgConfig {
        trunk: crate::Trunk::Mlp { hidden: vec![64] },
        actor_hidden: 64,
        critic_hidden: 64,
        critic_action_fc: 32,
        batch_size: 64,
        opt_len: 8,
        update_len: 8,
        scan_len: 16,
        tau: 0.005,
        actor_uses_updated_critic: false,
        scan_method: crate::ScanMethod::MaskedLoop,
        device: crate::DeviceSpec::Cpu,
        ..RdpgConfig::default()
    };
    if ddpg {
        cfg.ddpg()
    } else {
        cfg
    }
}
