//! Disordered set-ups (`jitter`): each particle of a lattice displaced by a uniform random vector
//! of up to ±f spacings per axis, so that every exact solution can also be checked off a lattice
//! (real flows are never lattices). The draws are a fixed function of (seed, phase, particle):
//! the same scene gives the same particles on every machine and build, whatever the thread count.

/// The stream of uniform numbers of one phase: SplitMix64 (Steele, Lea & Flood 2014), written
/// out here so that a crate's change of algorithm can never change a set-up.
struct SplitMix64(u64);

impl SplitMix64 {
    fn new(seed: u64, phase: u64) -> Self {
        // Distinct phases start far apart in the sequence (golden-ratio increments).
        SplitMix64(seed ^ phase.wrapping_mul(0xD6E8_FEB8_6659_FD93))
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [−1, 1) (53 random bits).
    fn symmetric(&mut self) -> f64 {
        let u = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        2.0 * u - 1.0
    }
}

/// Displace every point by a uniform random vector in [−f Δ, f Δ) along each of the first `dim`
/// axes (`f` = `amplitude`, Δ = `spacing`), wrapping into [0, len) on each axis. `phase` names
/// the phase (0 gas, k + 1 dust fraction k) so that the phases are drawn independently.
pub(crate) fn jitter(
    x: &mut [[f64; 3]],
    dim: u32,
    len: &[f64; 3],
    spacing: f64,
    amplitude: f64,
    seed: u64,
    phase: u64,
) {
    if amplitude == 0.0 {
        return;
    }
    let mut rng = SplitMix64::new(seed, phase);
    for p in x.iter_mut() {
        for (c, l) in p.iter_mut().zip(len).take(dim as usize) {
            *c = (*c + amplitude * spacing * rng.symmetric()).rem_euclid(*l);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jitter_is_uniform_within_its_bound_and_independent_per_phase() {
        let n = 20_000;
        let base = vec![[0.5, 0.5, 0.5]; n];
        let len = [1.0; 3];
        let draw = |phase| {
            let mut x = base.clone();
            jitter(&mut x, 3, &len, 0.1, 0.3, 7, phase);
            x
        };
        let (a, b) = (draw(0), draw(1));
        // Every displacement within ±0.03, mean ≈ 0, variance ≈ (0.03)²/3 per axis.
        let d: Vec<f64> = a.iter().flat_map(|p| p.iter().map(|c| c - 0.5)).collect();
        assert!(d.iter().all(|x| x.abs() <= 0.03));
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let var = d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64;
        assert!(mean.abs() < 3e-4, "mean {mean}");
        assert!(
            (var / (0.03f64.powi(2) / 3.0) - 1.0).abs() < 0.03,
            "var {var}"
        );
        // Two phases are not the same draw, and one phase is the same draw every time.
        assert!(a.iter().zip(&b).filter(|(p, q)| p == q).count() < 2);
        assert_eq!(a, draw(0));
        // Only the first `dim` axes move.
        let mut x = base.clone();
        jitter(&mut x, 1, &len, 0.1, 0.3, 7, 0);
        assert!(x.iter().all(|p| p[1] == 0.5 && p[2] == 0.5));
    }
}
