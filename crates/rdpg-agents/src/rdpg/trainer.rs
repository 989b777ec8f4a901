//! The off-policy training loop shared by RDPG, DDPG and SAC (Algorithm 1's outer loop).
//!
//! Acting runs on the shared [`Collector`] (N environments on worker threads) with batched
//! policy inference; every environment keeps its own recurrent actor state and exploration
//! noise. Each finished episode goes to the [`EpisodicReplay`] whole, and after the warm-up the
//! agent makes `updates_per_step` updates per environment step on windows sampled from it.
//!
//! Everything random is seeded: the networks (`seed`), the environments (the collector's seed
//! schedule), warm-up actions, noise and replay sampling (one [`NpRng`]). An
//! [`OffPolicyTrainer`] can be checkpointed at any step ([`Trainer::save`]) and resumed
//! ([`OffPolicyTrainer::load`]) bit-identically: episodes in progress are rebuilt from their
//! seed and actions.

use std::borrow::Borrow;
use std::path::Path;

use rdpg_core::noise::{
    action_distance, ActionNoise, AdaptiveParamNoise, Gaussian, OrnsteinUhlenbeck, OuConfig,
    ParamNoiseConfig,
};
use rdpg_core::replay::{Episode, EpisodicReplay, ReplayConfig, ReplayFormat3};
use rdpg_core::rng::NpRng;
use serde::{Deserialize, Serialize};

use super::agent::{ActorState, RdpgAgent};
use super::config::RdpgConfig;
use super::inject::TeacherFile;
use super::off_policy::{ExplorationConfig, OffPolicyConfig, PerturbSchedule};
use crate::common::checkpoint::{
    ckpt_err, read_bin, read_json, write_bin, write_json, Header, TrainerKind,
};
use crate::common::{
    evaluate_policy, Collector, DeterministicPolicy, EvalRecord, TrainConfig, TrainObserver,
    Trainer,
};
use crate::error::{AgentError, Result};

/// The transitions of an episode in progress, as the replay will store them.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct EpisodeBuffer {
    obs: Vec<f32>,
    /// Actions in the agent's normalised `[-1, 1]` space.
    actions: Vec<f32>,
    rewards: Vec<f32>,
    states: Vec<f32>,
}

/// The parameter noise of a run: σ, the perturbed parameters the envs act with (empty before
/// the first perturbation), whether to perturb before the next step and when by the step
/// schedule, and the updates since σ last adapted.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct ParamNoiseState {
    noise: AdaptiveParamNoise,
    acting: Vec<f32>,
    perturb_now: bool,
    next_perturb: u64,
    updates_since_adapt: u64,
}

/// The off-policy loop's own state, saved with a checkpoint as `loop.bin` (the collector's is
/// `collector.bin`).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct LoopState {
    update_debt: f64,
    rng: NpRng,
    noise: Vec<ActionNoise>,
    buffers: Vec<EpisodeBuffer>,
    actor_state: Vec<f32>,
    /// The trained (clean) actor's states when the envs act with a perturbed copy and the
    /// replay stores states: what burn-in starts from (empty otherwise).
    clean_state: Vec<f32>,
    param_noise: Option<ParamNoiseState>,
}

/// SAC explores by sampling its policy: action noise and parameter noise are refused for it,
/// by name.
fn check_sac_exploration(off: &OffPolicyConfig, agent: &RdpgConfig) -> Result<()> {
    if agent.sac.is_none() {
        return Ok(());
    }
    let why = "does not apply to sac, which explores by sampling its policy";
    if off.exploration != ExplorationConfig::None {
        return Err(AgentError::Config {
            field: "off_policy.exploration",
            reason: format!("{why} (set kind = \"none\")"),
        });
    }
    if off.param_noise.is_some() {
        return Err(AgentError::Config {
            field: "off_policy.param_noise",
            reason: why.into(),
        });
    }
    Ok(())
}

/// Off-policy training of an [`RdpgAgent`] (recurrent RDPG, feed-forward DDPG, or SAC).
pub struct OffPolicyTrainer {
    cfg: TrainConfig,
    off: OffPolicyConfig,
    agent: RdpgAgent,
    replay: EpisodicReplay,
    collector: Collector,
    act_state: ActorState,
    /// The trained actor run alongside the exploring one, for the stored states (see
    /// [`LoopState::clean_state`]); `None` when not needed.
    clean_state: Option<ActorState>,
    st: LoopState,
}

/// The replay buffer of the off-policy trainer checkpoint in `dir` (`checkpoints/latest` of a
/// run): every episode the agent learned from, with its stored acting-time states.
pub fn load_replay(dir: &Path) -> Result<EpisodicReplay> {
    read_replay(dir, Header::read(dir, Some(TrainerKind::OffPolicy))?)
}

fn read_replay(dir: &Path, header: Header) -> Result<EpisodicReplay> {
    let path = dir.join("replay.bin");
    if header.format == 3 {
        EpisodicReplay::try_from(read_bin::<ReplayFormat3>(&path)?).map_err(|e| ckpt_err(&path, e))
    } else {
        read_bin(&path)
    }
}

impl OffPolicyTrainer {
    /// A fresh run (validates all three configs).
    pub fn new(cfg: TrainConfig, off: OffPolicyConfig, agent_cfg: RdpgConfig) -> Result<Self> {
        cfg.validate()?;
        off.validate()?;
        check_sac_exploration(&off, &agent_cfg)?;
        if agent_cfg.flush_denormal {
            // Before any tensor work: libtorch's worker threads, created at its first parallel
            // region, inherit this thread's mode (the environments step in IEEE mode anyway).
            crate::common::tensor::set_flush_denormal(true);
        }
        let collector = Collector::new(&cfg)?;
        let (obs_dim, act_dim) = (collector.obs_dim(), collector.act_dim());
        let agent = RdpgAgent::new(agent_cfg, obs_dim, act_dim, cfg.seed)?;
        let state_dim = if agent.config().burn_in_from_stored_state {
            agent.state_dim()
        } else {
            0
        };
        let mut rcfg =
            ReplayConfig::new(off.replay_capacity, obs_dim, act_dim).with_state_dim(state_dim);
        if let Some(inj) = &off.injection {
            rcfg = rcfg.with_max_injected_fraction(inj.max_fraction);
        }
        let mut replay = EpisodicReplay::new(rcfg).map_err(|e| AgentError::Config {
            field: "replay",
            reason: e.to_string(),
        })?;
        for path in off.injection.iter().flat_map(|i| &i.teachers) {
            // The teacher's episodes replayed through this run's own env options; a
            // stored-state student gets its own actor's states along them (module docs of
            // `inject`).
            for mut ep in TeacherFile::load(path)?.episodes_for(&cfg, path)? {
                if state_dim > 0 {
                    ep.states = agent.episode_states(&ep.obs, ep.len())?;
                }
                replay.add_episode(ep).map_err(|e| AgentError::Config {
                    field: "off_policy.injection",
                    reason: format!("teacher {}: {e}", path.display()),
                })?;
            }
        }
        let n = cfg.num_envs;
        let st = LoopState {
            update_debt: 0.0,
            rng: NpRng::from_seed(cfg.seed ^ 0x5EED_F07E_A1A1),
            noise: (0..n)
                .map(|_| make_noise(&off.exploration, act_dim))
                .collect(),
            buffers: collector
                .obs()
                .iter()
                .map(|o| EpisodeBuffer {
                    obs: o.clone(),
                    ..Default::default()
                })
                .collect(),
            actor_state: Vec::new(),
            clean_state: Vec::new(),
            param_noise: off.param_noise.map(|p| ParamNoiseState {
                noise: AdaptiveParamNoise::new(ParamNoiseConfig {
                    initial_stddev: p.initial_stddev,
                    desired_action_stddev: p.desired_action_stddev,
                    adoption_coefficient: p.adoption_coefficient,
                }),
                acting: Vec::new(),
                perturb_now: true,
                next_perturb: 0,
                updates_since_adapt: 0,
            }),
        };
        let act_state = agent.initial_state(n);
        let clean_state =
            (state_dim > 0 && off.param_noise.is_some()).then(|| agent.initial_state(n));
        Ok(Self {
            cfg,
            off,
            agent,
            replay,
            collector,
            act_state,
            clean_state,
            st,
        })
    }

    /// Resumes a checkpoint written by [`Trainer::save`]; continuing gives the same result as
    /// never having stopped.
    pub fn load(dir: &Path) -> Result<Self> {
        let header = Header::read(dir, Some(TrainerKind::OffPolicy))?;
        let cfg: TrainConfig = read_json(&dir.join("train.json"))?;
        cfg.validate()?;
        let off: OffPolicyConfig = read_json(&dir.join("off_policy.json"))?;
        off.validate()?;
        let mut agent = RdpgAgent::load(dir.join("agent"))?;
        check_sac_exploration(&off, agent.config())?;
        let replay = read_replay(dir, header)?;
        let st: LoopState = read_bin(&dir.join("loop.bin"))?;
        let collector = Collector::restore(&cfg, read_bin(&dir.join("collector.bin"))?)?;
        let n = cfg.num_envs;
        if st.buffers.len() != n || st.noise.len() != n {
            return Err(ckpt_err(
                &dir.join("loop.bin"),
                "loop state does not match train.num_envs",
            ));
        }
        if (agent.obs_dim(), agent.act_dim()) != (collector.obs_dim(), collector.act_dim()) {
            return Err(ckpt_err(
                &dir.join("agent"),
                "the agent's observation/action sizes do not match the environment",
            ));
        }
        let rc = replay.config();
        let stored = if agent.config().burn_in_from_stored_state {
            agent.state_dim()
        } else {
            0
        };
        if (rc.obs_dim, rc.act_dim, rc.state_dim) != (agent.obs_dim(), agent.act_dim(), stored) {
            return Err(ckpt_err(
                &dir.join("replay.bin"),
                "the replay's observation/action/state sizes do not match the agent",
            ));
        }
        check_loop_state(&st, &off, n, agent.act_dim(), agent.obs_dim(), stored)
            .map_err(|e| ckpt_err(&dir.join("loop.bin"), e))?;
        if st.param_noise.is_some() != off.param_noise.is_some() {
            return Err(AgentError::Checkpoint(
                "parameter noise state does not match the config".into(),
            ));
        }
        if let Some(pn) = st.param_noise.as_ref().filter(|p| !p.acting.is_empty()) {
            agent
                .set_exploring_params(Some(&pn.acting))
                .map_err(|e| AgentError::Checkpoint(format!("parameter noise: {e}")))?;
        }
        let restore = |v: &[f32]| -> Result<ActorState> {
            let mut s = agent.initial_state(n);
            let sd = s.carried_len();
            if v.len() != n * sd {
                return Err(ckpt_err(
                    &dir.join("loop.bin"),
                    "actor state size does not match the agent",
                ));
            }
            for i in 0..n {
                if sd > 0 {
                    s.restore_env(i, &v[i * sd..(i + 1) * sd])
                        .map_err(|e| ckpt_err(&dir.join("loop.bin"), e))?;
                }
            }
            Ok(s)
        };
        let act_state = restore(&st.actor_state)?;
        let wants_clean = replay.config().state_dim > 0 && off.param_noise.is_some();
        let clean_state = wants_clean.then(|| restore(&st.clean_state)).transpose()?;
        Ok(Self {
            cfg,
            off,
            agent,
            replay,
            collector,
            act_state,
            clean_state,
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

    /// The off-policy settings.
    pub fn off_policy(&self) -> &OffPolicyConfig {
        &self.off
    }

    /// The replay buffer.
    pub fn replay(&self) -> &EpisodicReplay {
        &self.replay
    }

    /// σ of the parameter noise (`None` without parameter noise).
    pub fn param_noise_stddev(&self) -> Option<f64> {
        self.st.param_noise.as_ref().map(|p| p.noise.sigma)
    }

    /// Algorithm 1's `Noise()`: when due (an episode started, or the step schedule says so),
    /// explores from now on with a freshly perturbed copy of the trained actor.
    fn perturb_actor_if_due(&mut self) -> Result<()> {
        let (Some(pn), Some(spec)) = (self.st.param_noise.as_mut(), self.off.param_noise) else {
            return Ok(());
        };
        let steps = self.collector.steps();
        let due = match spec.perturb {
            PerturbSchedule::Episode => pn.perturb_now,
            PerturbSchedule::Steps(k) => {
                let due = pn.acting.is_empty() || steps >= pn.next_perturb;
                if due {
                    pn.next_perturb = steps + k;
                }
                due
            }
        };
        if !due {
            return Ok(());
        }
        pn.perturb_now = false;
        let mut params = self.agent.actor_params();
        pn.noise.perturb(&mut params, &mut self.st.rng);
        self.agent.set_exploring_params(Some(&params))?;
        pn.acting = params;
        Ok(())
    }

    /// Adapts σ after every `adapt_every_updates` updates (Plappert et al.): the distance is
    /// measured between the current actor and a fresh perturbation of it with the current σ,
    /// on the first observations of 64 windows sampled from the replay; then the acting copy
    /// is put back.
    fn adapt_param_noise_if_due(&mut self) -> Result<()> {
        let (Some(pn), Some(spec)) = (self.st.param_noise.as_mut(), self.off.param_noise) else {
            return Ok(());
        };
        pn.updates_since_adapt += 1;
        if pn.updates_since_adapt < spec.adapt_every_updates {
            return Ok(());
        }
        pn.updates_since_adapt = 0;
        let Some(b) = self.replay.sample(&mut self.st.rng, 64, 0, 1) else {
            return Ok(());
        };
        // obs [n, 2, obs_dim]: the first step of each window.
        let d = b.obs_dim;
        let obs: Vec<f32> = (0..b.n)
            .flat_map(|i| b.obs[i * 2 * d..i * 2 * d + d].iter().copied())
            .collect();
        adapt_param_noise(&mut self.agent, &mut pn.noise, &obs, &mut self.st.rng)?;
        if !pn.acting.is_empty() {
            self.agent.set_exploring_params(Some(&pn.acting))?;
        }
        Ok(())
    }

    /// Algorithm 1's `Update()` on sampled sub-trajectories, as many as the update rate has
    /// accrued.
    fn update_as_due(&mut self, n: usize, obs_cb: &mut dyn TrainObserver) -> Result<()> {
        self.st.update_debt += self.off.updates_per_step * n as f64;
        let c = self.agent.config();
        let (b, s, l) = (c.batch_size, c.scan_len, c.opt_len);
        let steps = self.collector.steps();
        while self.st.update_debt >= 1.0 {
            self.st.update_debt -= 1.0;
            let rng = &mut self.st.rng;
            let sampled = match &self.off.injection {
                // A share of the windows from teacher episodes, annealed to 0.
                Some(inj) => self.replay.sample_mixed(rng, b, s, l, inj.share(steps)),
                None => self.replay.sample(rng, b, s, l),
            };
            let Some(batch) = sampled else {
                break;
            };
            let stats = self.agent.update(&batch)?;
            obs_cb.on_update(steps, &stats);
            self.adapt_param_noise_if_due()?;
        }
        Ok(())
    }
}

impl OffPolicyTrainer {
    /// Switches `RdpgConfig::parallel_twins` (a speed setting that changes no number) for the
    /// rest of the run, e.g. when a resumed run gets a free core.
    pub fn set_parallel_twins(&mut self, on: bool) -> Result<()> {
        self.agent.set_parallel_twins(on)
    }
}

impl Trainer for OffPolicyTrainer {
    fn run(&mut self, until: u64, obs_cb: &mut dyn TrainObserver) -> Result<u64> {
        let until = until.min(self.cfg.total_steps);
        let n = self.cfg.num_envs;
        let act_dim = self.agent.act_dim();
        let stored = self.replay.config().state_dim > 0;
        while self.collector.steps() < until {
            if obs_cb.should_stop(self.collector.steps()) {
                break;
            }
            // Acting: a_t = mu(o_t, h_{t-1}) + N_t (Algorithm 1), uniform during warm-up. The
            // replay stores the trained actor's state h_{t-1} (for burn-in), also when the
            // envs act with a perturbed copy.
            let states: Vec<Vec<f32>> = if stored {
                let s = self.clean_state.as_ref().unwrap_or(&self.act_state);
                (0..n).map(|i| s.env_state(i)).collect()
            } else {
                vec![Vec::new(); n]
            };
            let warm = self.collector.steps() < self.off.warmup_steps;
            if !warm {
                self.perturb_actor_if_due()?;
            }
            let flat: Vec<f32> = self.collector.obs().concat();
            // SAC samples its policy (a = tanh(m + s eps)); the others act deterministically
            // and add their action noise below.
            let mu = if self.agent.config().sac.is_some() && !warm {
                let eps: Vec<f32> = (0..n * act_dim)
                    .map(|_| self.st.rng.standard_normal() as f32)
                    .collect();
                self.agent.act_sampled(&flat, &mut self.act_state, &eps)?
            } else {
                self.agent.act_exploring(&flat, &mut self.act_state)?
            };
            if let Some(clean) = self.clean_state.as_mut() {
                self.agent.act(&flat, clean)?;
            }
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
            let transitions = self.collector.step(&actions)?;
            for (i, t) in transitions.into_iter().enumerate() {
                let s = t.step;
                let buf = &mut self.st.buffers[i];
                buf.obs
                    .extend_from_slice(s.final_obs.as_ref().unwrap_or(&s.obs));
                buf.actions.extend_from_slice(&actions[i]);
                buf.rewards.push(s.reward as f32);
                buf.states.extend_from_slice(&states[i]);
                if let Some(rec) = t.finished {
                    let done = std::mem::replace(
                        buf,
                        EpisodeBuffer {
                            obs: s.obs,
                            ..Default::default()
                        },
                    );
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
                    if let Some(clean) = self.clean_state.as_mut() {
                        self.agent.reset_state(clean, Some(i));
                    }
                    self.st.noise[i].reset();
                    if let Some(pn) = self.st.param_noise.as_mut() {
                        pn.perturb_now = true;
                    }
                    obs_cb.on_episode(&rec);
                }
            }
            if !warm && self.replay.num_episodes() > 0 {
                self.update_as_due(n, obs_cb)?;
            }
            if self.collector.eval_due() {
                let rec = self.evaluate()?;
                obs_cb.on_eval(&rec);
            }
        }
        Ok(self.collector.steps())
    }

    fn evaluate(&mut self) -> Result<EvalRecord> {
        let (episodes, seed) = (self.cfg.eval_episodes, self.cfg.eval_seed);
        let mut rec =
            evaluate_policy(&mut RdpgPolicy::new(&self.agent), &self.cfg, episodes, seed)?;
        rec.step = self.collector.steps();
        Ok(rec)
    }

    fn save(&mut self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| ckpt_err(dir, e))?;
        Header::write(dir, TrainerKind::OffPolicy)?;
        self.agent.save(dir.join("agent"))?;
        self.st.actor_state = self.act_state.to_vec();
        self.st.clean_state = self
            .clean_state
            .as_ref()
            .map_or(Vec::new(), ActorState::to_vec);
        write_bin(&dir.join("replay.bin"), &self.replay)?;
        write_bin(&dir.join("loop.bin"), &self.st)?;
        write_bin(&dir.join("collector.bin"), self.collector.state())?;
        write_json(&dir.join("train.json"), &self.cfg)?;
        write_json(&dir.join("off_policy.json"), &self.off)?;
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

/// An [`RdpgAgent`] (owned or borrowed) as a [`DeterministicPolicy`]: the trained actor with
/// its own recurrent state.
pub struct RdpgPolicy<A> {
    agent: A,
    state: ActorState,
    /// [`DeterministicPolicy::limit_memory`]'s `k`, if set.
    memory: Option<usize>,
}

impl<A: Borrow<RdpgAgent>> RdpgPolicy<A> {
    /// Wraps `agent` (`RdpgAgent` or `&RdpgAgent`).
    pub fn new(agent: A) -> Self {
        let state = agent.borrow().initial_state(1);
        Self {
            agent,
            state,
            memory: None,
        }
    }
}

impl<A: Borrow<RdpgAgent>> DeterministicPolicy for RdpgPolicy<A> {
    fn begin_episode(&mut self) {
        let agent = self.agent.borrow();
        self.state = match self.memory {
            Some(k) => agent.state_with_window(1, k), // `k` checked by `limit_memory`
            None => agent.initial_state(1),
        };
    }
    fn limit_memory(&mut self, k: usize) -> Result<()> {
        self.agent.borrow().initial_state_with_memory(1, k)?;
        self.memory = Some(k);
        Ok(())
    }
    fn act(&mut self, obs: &[f32]) -> Result<Vec<f32>> {
        self.agent.borrow().act(obs, &mut self.state)
    }
    fn state(&self) -> Vec<f32> {
        self.state.to_vec()
    }
    fn set_state(&mut self, state: &[f32]) -> Result<()> {
        if let Some(k) = state.iter().position(|x| !x.is_finite()) {
            return Err(AgentError::Input(format!(
                "actor state value {k} is {}",
                state[k]
            )));
        }
        self.state.restore_env(0, state)
    }
}

/// One adaptation of parameter noise (Plappert et al. 2018): perturbs a fresh copy of the
/// agent's trained actor with `N(0, σ²)` (drawn from `rng`), measures the RMS distance between
/// its actions and the trained actor's on `obs` (`[n, obs_dim]`, each from a zero recurrent
/// state), and adapts σ towards `noise.desired_action_stddev`. Returns the distance. The
/// agent's exploring copy is left holding the fresh perturbation.
pub fn adapt_param_noise(
    agent: &mut RdpgAgent,
    noise: &mut AdaptiveParamNoise,
    obs: &[f32],
    rng: &mut NpRng,
) -> Result<f64> {
    let n = obs.len() / agent.obs_dim();
    let mut params = agent.actor_params();
    noise.perturb(&mut params, rng);
    agent.set_exploring_params(Some(&params))?;
    let perturbed = agent.act_exploring(obs, &mut agent.initial_state(n))?;
    let clean = agent.act(obs, &mut agent.initial_state(n))?;
    let distance = action_distance(&perturbed, &clean);
    noise.adapt(distance);
    Ok(distance)
}

/// What a loaded `loop.bin` must agree with: the update debt is what one vector step leaves,
/// each env's noise is the configured process on the action size (an OU state finite), each
/// open episode's buffers have whole steps of the agent's sizes.
fn check_loop_state(
    st: &LoopState,
    off: &OffPolicyConfig,
    n: usize,
    act_dim: usize,
    obs_dim: usize,
    state_dim: usize,
) -> std::result::Result<(), String> {
    let most = off.updates_per_step * n as f64 + 1.0;
    if !(0.0..=most).contains(&st.update_debt) {
        return Err(format!(
            "update debt {} is not from 0 to {most}",
            st.update_debt
        ));
    }
    for (i, noise) in st.noise.iter().enumerate() {
        let fresh = make_noise(&off.exploration, act_dim);
        let same = match (noise, &fresh) {
            (ActionNoise::Ou(a), ActionNoise::Ou(b)) => {
                (a.theta, a.sigma, a.mu, a.dt, a.state.len())
                    == (b.theta, b.sigma, b.mu, b.dt, b.state.len())
                    && a.state.iter().all(|x| x.is_finite())
            }
            (a, b) => a == b,
        };
        if !same {
            return Err(format!(
                "env {i}'s exploration noise does not match off_policy.exploration on {act_dim} \
                 action components"
            ));
        }
    }
    for (i, b) in st.buffers.iter().enumerate() {
        let k = b.rewards.len();
        let fits = b.obs.len() == (k + 1) * obs_dim
            && b.actions.len() == k * act_dim
            && b.states.len() == k * state_dim;
        if !fits {
            return Err(format!(
                "env {i}'s open episode holds {} observation, {} action and {} state values \
                 for {k} steps",
                b.obs.len(),
                b.actions.len(),
                b.states.len()
            ));
        }
    }
    Ok(())
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
