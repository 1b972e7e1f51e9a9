//! nerfacto's proposal-network schedules (spec/nerfacto.md §2.7): when proposals get gradients, and the weight
//! annealing exponent used for resampling.

use super::config::SamplingConfig;

/// update_sched(step) = clip(interp(step, [0, warmup], [0, update_every]), 1, update_every).
pub fn update_every_at(s: &SamplingConfig, step: u64) -> f64 {
    let every = s.proposal_update_every as f64;
    let x = if s.proposal_warmup == 0 { every } else { every * (step as f64 / s.proposal_warmup as f64).min(1.0) };
    x.clamp(1.0, every.max(1.0))
}

/// Anneal exponent 10 f / (9 f + 1) with f = clip(step / max_iters, 0, 1) (slope 10); 1 when annealing is off.
pub fn anneal_at(s: &SamplingConfig, step: u64) -> f32 {
    if !s.use_proposal_weight_anneal {
        return 1.0;
    }
    let f = if s.proposal_weights_anneal_max_num_iters == 0 {
        1.0
    } else {
        (step as f64 / s.proposal_weights_anneal_max_num_iters as f64).clamp(0.0, 1.0)
    };
    let k = s.proposal_weights_anneal_slope;
    (k * f / ((k - 1.0) * f + 1.0)) as f32
}

/// The proposal update cadence: `decide` is called once per training step.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ProposalSchedule {
    pub steps_since_update: u64,
}

impl ProposalSchedule {
    /// Whether proposals get gradients at `step`; advances the counter as nerfstudio does (reset when updated,
    /// then +1 after every step).
    pub fn decide(&mut self, s: &SamplingConfig, step: u64) -> bool {
        let updated = self.steps_since_update as f64 > update_every_at(s, step) || step < 10;
        if updated {
            self.steps_since_update = 0;
        }
        self.steps_since_update += 1;
        updated
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nerf::config::ModelConfig;

    #[test]
    fn cadence_matches_nerfacto() {
        let cfg = ModelConfig::resolve("nerfacto").expect("built-in");
        let s = &cfg.sampling;
        let mut sched = ProposalSchedule::default();
        let updates: Vec<u64> = (0..6000).filter(|&k| sched.decide(s, k)).collect();
        // Every step below 10, every 2nd until 2000, ..., every 6th after 5000 (spec/nerfacto.md §2.7).
        assert_eq!(&updates[..10], &(0..10).collect::<Vec<_>>()[..]);
        let gaps_at = |lo: u64, hi: u64| -> Vec<u64> {
            updates.windows(2).filter(|w| w[0] >= lo && w[1] < hi).map(|w| w[1] - w[0]).collect()
        };
        assert!(gaps_at(100, 1900).iter().all(|&g| g == 2));
        assert!(gaps_at(2100, 2900).iter().all(|&g| g == 3));
        assert!(gaps_at(5100, 6000).iter().all(|&g| g == 6));
        assert_eq!(anneal_at(s, 0), 0.0);
        assert!((anneal_at(s, 100) - 10.0 * 0.1 / (9.0 * 0.1 + 1.0)).abs() < 1e-6);
        assert_eq!(anneal_at(s, 5000), 1.0);
    }
}
