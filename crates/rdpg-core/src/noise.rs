//! Exploration noise: Ornstein-Uhlenbeck and Gaussian action noise, and adaptive parameter
//! noise (Plappert et al. 2018), all driven by the numpy-compatible [`NpRng`].
//!
//! Every noise process is plain data (`Serialize` / `Deserialize`) so a checkpoint resumes it
//! exactly. Components are drawn in index order, one `standard_normal` each, so a sequence of
//! draws is reproducible from the generator's seed.

use serde::{Deserialize, Serialize};

use crate::rng::NpRng;

/// Parameters of an [`OrnsteinUhlenbeck`] process.
///
/// The defaults are the usual DDPG values `theta = 0.15`, `sigma = 0.2`, `mu = 0`, `dt = 1`.
/// The authors' released RDPG code (sdr2002/RDPG-Biped) used a much smaller process,
/// `theta = 0.023`, `sigma = 0.02` (see [`OuConfig::authors_code`]), reset every episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OuConfig {
    /// Mean-reversion rate.
    pub theta: f64,
    /// Scale of the driving Gaussian noise.
    pub sigma: f64,
    /// Long-run mean (the same for every component).
    pub mu: f64,
    /// Time step.
    pub dt: f64,
}

impl Default for OuConfig {
    fn default() -> Self {
        Self {
            theta: 0.15,
            sigma: 0.2,
            mu: 0.0,
            dt: 1.0,
        }
    }
}

impl OuConfig {
    /// The values in the authors' released code: `theta = 0.023`, `sigma = 0.02`, `mu = 0`,
    /// `dt = 1` (stationary std about 0.093).
    pub fn authors_code() -> Self {
        Self {
            theta: 0.023,
            sigma: 0.02,
            mu: 0.0,
            dt: 1.0,
        }
    }
}

/// Ornstein-Uhlenbeck action noise, one independent process per action component:
/// `x ← x + theta (mu - x) dt + sigma sqrt(dt) N(0, 1)`.
///
/// The state starts at zero and [`reset`](Self::reset) sets it back to zero (as OpenAI
/// baselines do); the paper resets it at the start of every episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OrnsteinUhlenbeck {
    /// Mean-reversion rate.
    pub theta: f64,
    /// Scale of the driving noise.
    pub sigma: f64,
    /// Long-run mean.
    pub mu: f64,
    /// Time step.
    pub dt: f64,
    /// Current value of each component.
    pub state: Vec<f64>,
}

impl OrnsteinUhlenbeck {
    /// A `dim`-dimensional process at state zero.
    pub fn new(dim: usize, config: OuConfig) -> Self {
        Self {
            theta: config.theta,
            sigma: config.sigma,
            mu: config.mu,
            dt: config.dt,
            state: vec![0.0; dim],
        }
    }

    /// Number of components.
    pub fn dim(&self) -> usize {
        self.state.len()
    }

    /// Sets every component back to zero.
    pub fn reset(&mut self) {
        self.state.iter_mut().for_each(|x| *x = 0.0);
    }

    /// Advances the process one step (one `standard_normal` per component, in order) and
    /// returns the new state.
    pub fn sample(&mut self, rng: &mut NpRng) -> Vec<f32> {
        let scale = self.sigma * self.dt.sqrt();
        self.state
            .iter_mut()
            .map(|x| {
                *x += self.theta * (self.mu - *x) * self.dt + scale * rng.standard_normal();
                *x as f32
            })
            .collect()
    }

    /// Standard deviation of the stationary distribution of this discrete-time process,
    /// `sigma sqrt(dt) / sqrt(1 - (1 - theta dt)^2)`; it tends to the continuous-time value
    /// `sigma / sqrt(2 theta)` as `dt → 0`. Infinite when `theta dt` is outside `(0, 2)`.
    pub fn stationary_std(&self) -> f64 {
        let a = 1.0 - self.theta * self.dt;
        let denom = 1.0 - a * a;
        if denom <= 0.0 {
            f64::INFINITY
        } else {
            self.sigma * self.dt.sqrt() / denom.sqrt()
        }
    }
}

/// Independent Gaussian action noise `N(0, sigma^2)` per component.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Gaussian {
    /// Standard deviation.
    pub sigma: f64,
    /// Number of components.
    pub dim: usize,
}

impl Gaussian {
    /// Noise of standard deviation `sigma` on `dim` components.
    pub fn new(dim: usize, sigma: f64) -> Self {
        Self { sigma, dim }
    }

    /// One draw (one `standard_normal` per component, in order).
    pub fn sample(&self, rng: &mut NpRng) -> Vec<f32> {
        (0..self.dim)
            .map(|_| (self.sigma * rng.standard_normal()) as f32)
            .collect()
    }
}

/// Action noise as a configurable choice, for agents that pick it at run time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum ActionNoise {
    /// No action noise (e.g. when parameter noise alone explores).
    None {
        /// Number of action components.
        dim: usize,
    },
    /// Ornstein-Uhlenbeck noise.
    Ou(OrnsteinUhlenbeck),
    /// Gaussian noise.
    Gaussian(Gaussian),
}

impl ActionNoise {
    /// Resets the process at an episode start (a no-op for memoryless noise).
    pub fn reset(&mut self) {
        if let Self::Ou(ou) = self {
            ou.reset();
        }
    }

    /// One draw of the noise to add to the action.
    pub fn sample(&mut self, rng: &mut NpRng) -> Vec<f32> {
        match self {
            Self::None { dim } => vec![0.0; *dim],
            Self::Ou(ou) => ou.sample(rng),
            Self::Gaussian(g) => g.sample(rng),
        }
    }
}

/// Parameters of [`AdaptiveParamNoise`]; the defaults are those of OpenAI baselines'
/// `AdaptiveParamNoiseSpec` (0.1, 0.1, 1.01).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ParamNoiseConfig {
    /// Initial parameter-noise standard deviation.
    pub initial_stddev: f64,
    /// Target RMS distance between the perturbed and unperturbed policies' actions.
    pub desired_action_stddev: f64,
    /// Multiplicative step of the adaptation (`> 1`).
    pub adoption_coefficient: f64,
}

impl Default for ParamNoiseConfig {
    fn default() -> Self {
        Self {
            initial_stddev: 0.1,
            desired_action_stddev: 0.1,
            adoption_coefficient: 1.01,
        }
    }
}

/// Adaptive parameter-space noise (Plappert et al., "Parameter Space Noise for
/// Exploration", ICLR 2018), which the paper applies periodically to the actor.
///
/// The learner perturbs a copy of the actor's parameters with [`perturb`](Self::perturb),
/// measures how far the perturbed policy's actions move with [`action_distance`] on a batch
/// of observations, and calls [`adapt`](Self::adapt) so that distance tracks
/// `desired_action_stddev`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdaptiveParamNoise {
    /// Current standard deviation of the parameter perturbation.
    pub sigma: f64,
    /// Target action-space distance.
    pub desired_action_stddev: f64,
    /// Multiplicative adaptation step.
    pub adoption_coefficient: f64,
}

impl Default for AdaptiveParamNoise {
    fn default() -> Self {
        Self::new(ParamNoiseConfig::default())
    }
}

impl AdaptiveParamNoise {
    /// A new adaptive noise at `config.initial_stddev`.
    pub fn new(config: ParamNoiseConfig) -> Self {
        Self {
            sigma: config.initial_stddev,
            desired_action_stddev: config.desired_action_stddev,
            adoption_coefficient: config.adoption_coefficient,
        }
    }

    /// Adapts `sigma` to a measured action distance: multiplied by `adoption_coefficient` if
    /// `distance < desired_action_stddev` (perturbation too weak), divided by it otherwise. A
    /// non-finite distance leaves `sigma` unchanged.
    pub fn adapt(&mut self, distance: f64) {
        if !distance.is_finite() {
            return;
        }
        if distance < self.desired_action_stddev {
            self.sigma *= self.adoption_coefficient;
        } else {
            self.sigma /= self.adoption_coefficient;
        }
    }

    /// Adds `N(0, sigma^2)` to every parameter, in order (one `standard_normal` each).
    pub fn perturb(&self, params: &mut [f32], rng: &mut NpRng) {
        for p in params {
            *p += (self.sigma * rng.standard_normal()) as f32;
        }
    }
}

/// Root-mean-square difference between two action arrays of the same shape,
/// `sqrt(mean((a - b)^2))` over all components (baselines' DDPG distance); 0 for empty input.
///
/// # Panics
///
/// If the lengths differ.
pub fn action_distance(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len(), "action_distance: lengths differ");
    if a.is_empty() {
        return 0.0;
    }
    let ss: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| {
            let d = f64::from(x) - f64::from(y);
            d * d
        })
        .sum();
    (ss / a.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mean_std(xs: &[f64]) -> (f64, f64) {
        let n = xs.len() as f64;
        let m = xs.iter().sum::<f64>() / n;
        let v = xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n;
        (m, v.sqrt())
    }

    #[test]
    fn ou_stationary_std_matches_theory() {
        let mut rng = NpRng::from_seed(1);
        let mut ou = OrnsteinUhlenbeck::new(2, OuConfig::default());
        for _ in 0..1_000 {
            ou.sample(&mut rng);
        }
        let mut xs = Vec::new();
        for _ in 0..200_000 {
            let s = ou.sample(&mut rng);
            xs.push(f64::from(s[0]));
            xs.push(f64::from(s[1]));
        }
        let (m, s) = mean_std(&xs);
        let expected = ou.stationary_std();
        // Discrete value sigma / sqrt(2 theta - theta^2) for dt = 1.
        assert!((expected - 0.2 / (0.3f64 - 0.0225).sqrt()).abs() < 1e-12);
        assert!(
            (s - expected).abs() / expected < 0.03,
            "std {s} vs {expected}"
        );
        assert!(m.abs() < 0.03, "mean {m}");
    }

    #[test]
    fn ou_small_dt_approaches_continuous_std() {
        let cfg = OuConfig {
            theta: 0.5,
            sigma: 0.3,
            mu: 0.0,
            dt: 0.01,
        };
        let mut rng = NpRng::from_seed(7);
        let mut ou = OrnsteinUhlenbeck::new(1, cfg);
        for _ in 0..2_000 {
            ou.sample(&mut rng);
        }
        let xs: Vec<f64> = (0..400_000)
            .map(|_| f64::from(ou.sample(&mut rng)[0]))
            .collect();
        let (_, s) = mean_std(&xs);
        let continuous = 0.3 / (2.0f64 * 0.5).sqrt();
        assert!((ou.stationary_std() - continuous).abs() / continuous < 0.01);
        assert!(
            (s - continuous).abs() / continuous < 0.06,
            "{s} vs {continuous}"
        );
    }

    #[test]
    fn ou_reverts_to_mean() {
        // Without driving noise the state decays geometrically towards mu.
        let cfg = OuConfig {
            theta: 0.2,
            sigma: 0.0,
            mu: 1.0,
            dt: 1.0,
        };
        let mut ou = OrnsteinUhlenbeck::new(1, cfg);
        ou.state[0] = 5.0;
        let mut rng = NpRng::from_seed(0);
        let x1 = ou.sample(&mut rng)[0];
        assert!((f64::from(x1) - (5.0 - 0.2 * 4.0)).abs() < 1e-6);
        for _ in 0..200 {
            ou.sample(&mut rng);
        }
        assert!((ou.state[0] - 1.0).abs() < 1e-9);

        // With noise, the average over many runs started far away moves towards mu by the
        // factor (1 - theta dt)^k.
        let cfg = OuConfig {
            theta: 0.15,
            sigma: 0.2,
            mu: 0.0,
            dt: 1.0,
        };
        let mut ou = OrnsteinUhlenbeck::new(4_000, cfg);
        ou.state.iter_mut().for_each(|x| *x = 2.0);
        for _ in 0..5 {
            ou.sample(&mut rng);
        }
        let mean = ou.state.iter().sum::<f64>() / ou.state.len() as f64;
        let expected = 2.0 * 0.85f64.powi(5);
        assert!((mean - expected).abs() < 0.02, "{mean} vs {expected}");
    }

    #[test]
    fn ou_reset_zeroes_state() {
        let mut rng = NpRng::from_seed(3);
        let mut ou = OrnsteinUhlenbeck::new(4, OuConfig::authors_code());
        for _ in 0..10 {
            ou.sample(&mut rng);
        }
        assert!(ou.state.iter().any(|&x| x != 0.0));
        ou.reset();
        assert_eq!(ou.state, vec![0.0; 4]);
        assert_eq!(ou.dim(), 4);
    }

    #[test]
    fn noise_is_deterministic_given_seed() {
        let run = |seed| {
            let mut rng = NpRng::from_seed(seed);
            let mut ou = OrnsteinUhlenbeck::new(4, OuConfig::default());
            let g = Gaussian::new(4, 0.3);
            let p = AdaptiveParamNoise::default();
            let mut params = vec![1.0f32; 16];
            let mut out = Vec::new();
            for _ in 0..20 {
                out.extend(ou.sample(&mut rng));
                out.extend(g.sample(&mut rng));
            }
            p.perturb(&mut params, &mut rng);
            out.extend(params);
            out
        };
        assert_eq!(run(42), run(42));
        assert_ne!(run(42), run(43));
    }

    #[test]
    fn ou_serde_round_trip_resumes_identically() {
        let mut rng = NpRng::from_seed(5);
        let mut ou = OrnsteinUhlenbeck::new(3, OuConfig::default());
        for _ in 0..7 {
            ou.sample(&mut rng);
        }
        let json = serde_json::to_string(&(&ou, &rng)).unwrap();
        let (mut ou2, mut rng2): (OrnsteinUhlenbeck, NpRng) = serde_json::from_str(&json).unwrap();
        assert_eq!(ou, ou2);
        for _ in 0..5 {
            assert_eq!(ou.sample(&mut rng), ou2.sample(&mut rng2));
        }
        let noise = ActionNoise::Ou(ou);
        let back: ActionNoise =
            serde_json::from_str(&serde_json::to_string(&noise).unwrap()).unwrap();
        assert_eq!(noise, back);
        let p = AdaptiveParamNoise::default();
        let back: AdaptiveParamNoise =
            serde_json::from_str(&serde_json::to_string(&p).unwrap()).unwrap();
        assert_eq!(p, back);
    }

    #[test]
    fn gaussian_statistics() {
        let mut rng = NpRng::from_seed(11);
        let g = Gaussian::new(2, 0.3);
        let xs: Vec<f64> = (0..50_000)
            .flat_map(|_| g.sample(&mut rng))
            .map(f64::from)
            .collect();
        let (m, s) = mean_std(&xs);
        assert!(m.abs() < 0.01, "{m}");
        assert!((s - 0.3).abs() < 0.01, "{s}");
    }

    #[test]
    fn action_noise_enum_dispatch() {
        let mut rng = NpRng::from_seed(2);
        let mut none = ActionNoise::None { dim: 3 };
        assert_eq!(none.sample(&mut rng), vec![0.0; 3]);
        let mut ou = ActionNoise::Ou(OrnsteinUhlenbeck::new(2, OuConfig::default()));
        ou.sample(&mut rng);
        ou.reset();
        if let ActionNoise::Ou(inner) = &ou {
            assert_eq!(inner.state, vec![0.0; 2]);
        }
        let mut g = ActionNoise::Gaussian(Gaussian::new(5, 0.1));
        assert_eq!(g.sample(&mut rng).len(), 5);
    }

    #[test]
    fn param_noise_adapts() {
        let mut p = AdaptiveParamNoise::new(ParamNoiseConfig {
            initial_stddev: 0.1,
            desired_action_stddev: 0.2,
            adoption_coefficient: 1.01,
        });
        p.adapt(0.05);
        assert!((p.sigma - 0.101).abs() < 1e-12, "grows when too close");
        p.adapt(0.5);
        p.adapt(0.5);
        assert!(
            (p.sigma - 0.101 / 1.01 / 1.01).abs() < 1e-12,
            "shrinks when too far"
        );
        let before = p.sigma;
        p.adapt(f64::NAN);
        assert_eq!(p.sigma, before);
    }

    #[test]
    fn param_noise_closed_loop_tracks_target() {
        // A linear "policy" a = W o: the action distance after perturbing W grows with sigma,
        // so repeated adaptation should settle sigma where the distance is near the target.
        let mut rng = NpRng::from_seed(9);
        let mut p = AdaptiveParamNoise::new(ParamNoiseConfig {
            initial_stddev: 1.0,
            desired_action_stddev: 0.2,
            adoption_coefficient: 1.05,
        });
        let obs: Vec<f32> = (0..64).map(|i| ((i % 7) as f32 - 3.0) / 3.0).collect();
        let w = vec![0.5f32; 8];
        let act = |w: &[f32]| -> Vec<f32> {
            obs.chunks(8)
                .map(|o| o.iter().zip(w).map(|(a, b)| a * b).sum())
                .collect()
        };
        let clean = act(&w);
        let mut late = Vec::new();
        for k in 0..600 {
            let mut pw = w.clone();
            p.perturb(&mut pw, &mut rng);
            let d = action_distance(&act(&pw), &clean);
            p.adapt(d);
            if k >= 300 {
                late.push(d);
            }
        }
        let (mean_d, _) = mean_std(&late);
        assert!(
            p.sigma < 0.5,
            "sigma shrank from its too-large start: {}",
            p.sigma
        );
        assert!((mean_d - 0.2).abs() < 0.06, "settled distance {mean_d}");
    }

    #[test]
    fn perturb_adds_gaussian_of_sigma() {
        let mut rng = NpRng::from_seed(4);
        let p = AdaptiveParamNoise::new(ParamNoiseConfig {
            initial_stddev: 0.5,
            ..ParamNoiseConfig::default()
        });
        let mut params = vec![2.0f32; 100_000];
        p.perturb(&mut params, &mut rng);
        let xs: Vec<f64> = params.iter().map(|&x| f64::from(x) - 2.0).collect();
        let (m, s) = mean_std(&xs);
        assert!(m.abs() < 0.01 && (s - 0.5).abs() < 0.01, "{m} {s}");
    }

    #[test]
    fn action_distance_is_rms() {
        assert_eq!(action_distance(&[], &[]), 0.0);
        // Differences [3, 4, 0, 0]: sqrt((9 + 16) / 4) = 2.5.
        let d = action_distance(&[3.0, 4.0, 1.0, 1.0], &[0.0, 0.0, 1.0, 1.0]);
        assert!((d - 2.5).abs() < 1e-12);
    }
}
