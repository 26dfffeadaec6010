//! The ranks' balance: their work per step judged, and the cut by measured cost it calls for.
use super::{max_over, sum_over, Comm, RankStepper};

/// The ranks' work per step may exceed its mean by this much before the next cut shares out
/// their measured cost per particle instead ([`RankStepper::judge_balance`]);
/// The scene key `numerics.rebalance_at` sets another (0: at every judgement; `inf`: never).
pub const REBALANCE_AT: f64 = 0.05;

/// Steps of work measured before the ranks' balance is judged (the cuts between keep the last
/// cost): fewer are dominated by this machine's noise.
pub(super) const REBALANCE_STEPS: u64 = 4;

impl RankStepper {
    /// How many particles this rank owns (its host copy less its ghosts after a step).
    fn own_len(&self) -> usize {
        match (&self.resident, self.owned_stale) {
            (Some(r), true) => r.flags.iter().filter(|&&g| !g).count(),
            _ => self.own.len(),
        }
    }

    /// Whether the ranks' work per step since the last judgement (their steps' time less their
    /// time in MPI, where they wait for each other; [`REBALANCE_STEPS`] or more) is uneven
    /// enough to rebuild the halo on a cut by cost now (collective): where the busiest rank's
    /// exceeds the mean by more than `rebalance_at`, the next cut shares out each rank's work
    /// per owned particle over the ranks' mean (kept until the next imbalance: it holds the
    /// cut where it balanced the ranks), and the halo is rebuilt at once where the wait it
    /// saves over `horizon` steps exceeds a build's `build_seconds` (docs/scaling.md, "Cut").
    pub(super) fn judge_balance(&mut self, horizon: f64, build_seconds: f64) -> bool {
        let world = &self.world;
        let n = self.own_len() as f64;
        let per_step = self.busy / self.busy_steps as f64;
        (self.busy, self.busy_steps) = (0.0, 0);
        let sums = sum_over(world, Work { per_step, n });
        let most = max_over(
            world,
            Slowest {
                per_step,
                build_seconds,
            },
        );
        let mean = sums.per_step / world.size() as f64;
        let uneven = mean > 0.0 && most.per_step > (1.0 + self.rebalance_at) * mean;
        let worth = (most.per_step - mean) * horizon > most.build_seconds;
        if self.trace && world.rank() == 0 {
            eprintln!(
                "halo: the busiest rank's work {:.4e} s a step against the mean {mean:.4e} s{}",
                most.per_step,
                match (uneven, worth) {
                    (true, true) => ": cut by the measured cost now",
                    (true, false) => ": cut by the measured cost at the next build",
                    _ => "",
                }
            );
        }
        if !uneven {
            return false;
        }
        // An empty rank has no cost per particle of its own: the mean's.
        let mean_per_particle = sums.per_step / sums.n.max(1.0);
        self.cost = Some(match n > 0.0 {
            true => (per_step / n) / mean_per_particle,
            false => 1.0,
        });
        worth
    }
}

/// The ranks' work per step and owned particles, summed over the ranks
/// ([`RankStepper::judge_balance`]).
#[repr(C)]
#[derive(Clone, Copy)]
struct Work {
    per_step: f64,
    n: f64,
}

/// The busiest rank's work per step and the slowest build, the maxima over the ranks
/// ([`RankStepper::judge_balance`]).
#[repr(C)]
#[derive(Clone, Copy)]
struct Slowest {
    per_step: f64,
    build_seconds: f64,
}

// SAFETY: `repr(C)` of f64 fields only (no padding), and every bit pattern is a valid f64.
unsafe impl bytemuck::Zeroable for Work {}
unsafe impl bytemuck::Pod for Work {}
unsafe impl bytemuck::Zeroable for Slowest {}
unsafe impl bytemuck::Pod for Slowest {}
