//! A particle's own time-step limits and its power-of-two time bin (method.md §T). The global
//! step takes the smallest limit over all particles; the bins say what each particle alone
//! would need.
use crate::Real;

/// The CFL limit h / v_sig (factor 1); +∞ without a signal speed.
#[inline(always)]
pub fn cfl_limit<R: Real>(h: R, vsig: R) -> R {
    if vsig > R::ZERO {
        h / vsig
    } else {
        R::from_f64(f64::INFINITY)
    }
}

/// The force limit sqrt(h / |a|) (factor 1); +∞ without a force.
#[inline(always)]
pub fn force_limit<R: Real>(h: R, acc: R) -> R {
    if acc > R::ZERO {
        (h / acc).sqrt()
    } else {
        R::from_f64(f64::INFINITY)
    }
}

/// A grain's |B| for the force limit: the external acceleration plus the point mass's pull (the
/// edge zones' damping is limited by its rate instead, τ ≤ 1/rate). Positions alone: a
/// checkpoint's or a rank's rebuilt engine recomputes it exactly.
#[inline(always)]
pub fn dust_pull(
    pm: &crate::gravity::PointMass,
    ext: crate::Vec3<f64>,
    x: crate::Vec3<f64>,
) -> f64 {
    let b = crate::add(ext, pm.accel(x));
    crate::dot(b, b).sqrt()
}

/// The bin of a particle whose own step is `dt_own`, bins being 2^j × `dt_min` (j = 0 the
/// shortest): the largest j ≤ `max_bin` with 2^j dt_min ≤ dt_own, so that a particle never
/// steps longer than its own limit (0 when dt_own ≤ dt_min).
#[inline(always)]
pub fn bin_of(dt_own: f64, dt_min: f64, max_bin: u32) -> u32 {
    let mut j = 0;
    let mut step = 2.0 * dt_min;
    while j < max_bin && step <= dt_own {
        j += 1;
        step *= 2.0;
    }
    j
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bin_never_steps_past_the_particles_own_limit_nor_below_half_of_it() {
        let dt_min = 0.3;
        for &own in &[0.3, 0.31, 0.59, 0.6, 0.61, 1.19, 1.2, 7.5, 1e3] {
            let j = bin_of(own, dt_min, 30);
            let step = dt_min * f64::powi(2.0, j as i32);
            assert!(step <= own, "own {own}: bin {j} steps {step}");
            assert!(2.0 * step > own, "own {own}: bin {j} is one bin too short");
        }
        assert_eq!(bin_of(1e3, dt_min, 4), 4, "capped at max_bin");
        assert_eq!(bin_of(0.1, dt_min, 4), 0, "below dt_min: the shortest bin");
    }
}
