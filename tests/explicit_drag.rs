//! The explicit drag baseline (`[drag] method = "explicit"`): the same particle equations and
//! cell means as IDIC with the drag at the known velocities. It must conserve momentum exactly,
//! be stable exactly up to its limit τ ≤ 0.9/Λ (Λ = max 1/t_k + Σ ε_k/t_k), converge at first
//! order, and the run must obey the limit whatever `time.dt` asks.
mod common;
use common::*;
use dustsph_device::drag::{explicit_dust_update, explicit_gas_update, explicit_rate};

type V = [f64; 3];

/// One cell: gas particles (m, v) and per fraction dust particles (m, u).
struct Cell {
    gas: Vec<(f64, V)>,
    dust: Vec<Vec<(f64, V)>>,
    t_stop: Vec<f64>,
}

fn mean(p: &[(f64, V)]) -> (f64, V) {
    let m: f64 = p.iter().map(|q| q.0).sum();
    let mut s = [0.0; 3];
    for (mi, v) in p {
        for d in 0..3 {
            s[d] += mi * v[d];
        }
    }
    (m, [s[0] / m, s[1] / m, s[2] / m])
}

impl Cell {
    fn random(r: &mut Rng, nf: usize) -> Cell {
        let mut vec = |s: f64| [r.range(-s, s), r.range(-s, s), r.range(-s, s)];
        let gas = (0..3).map(|_| (0.0, vec(1.0))).collect::<Vec<_>>();
        let dust = (0..nf)
            .map(|_| (0..2).map(|_| (0.0, vec(2.0))).collect())
            .collect();
        let mut c = Cell {
            gas,
            dust,
            t_stop: (0..nf).map(|_| r.log(1e-6, 1.0)).collect(),
        };
        for g in &mut c.gas {
            g.0 = r.range(0.5, 2.0);
        }
        for f in &mut c.dust {
            for d in f {
                d.0 = r.log(1e-3, 1e2);
            }
        }
        c
    }

    fn momentum(&self) -> (V, f64) {
        let mut p = [0.0; 3];
        let mut scale = 0.0;
        for (m, v) in self.gas.iter().chain(self.dust.iter().flatten()) {
            for d in 0..3 {
                p[d] += m * v[d];
            }
            scale += m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        }
        (p, scale)
    }

    fn eps(&self) -> Vec<f64> {
        let mg = mean(&self.gas).0;
        self.dust.iter().map(|f| mean(f).0 / mg).collect()
    }

    fn rate(&self) -> f64 {
        let inv: Vec<f64> = self.t_stop.iter().map(|t| 1.0 / t).collect();
        explicit_rate(&self.eps(), &inv)
    }

    /// One explicit drag step of size τ (no pressure: ṽ = v).
    fn step(&mut self, tau: f64) {
        let eps = self.eps();
        let beta: Vec<f64> = self.t_stop.iter().map(|t| tau / t).collect();
        let vbar = mean(&self.gas).1;
        let ubar: Vec<V> = self.dust.iter().map(|f| mean(f).1).collect();
        for g in &mut self.gas {
            g.1 = explicit_gas_update(g.1, &eps, &beta, &ubar);
        }
        for (k, f) in self.dust.iter_mut().enumerate() {
            for d in f {
                d.1 = explicit_dust_update(d.1, beta[k], vbar);
            }
        }
    }

    /// Largest |velocity − barycentric velocity| over all particles.
    fn spread(&self) -> f64 {
        let all: Vec<(f64, V)> = self
            .gas
            .iter()
            .chain(self.dust.iter().flatten())
            .copied()
            .collect();
        let bary = mean(&all).1;
        all.iter()
            .map(|(_, v)| (0..3).map(|d| (v[d] - bary[d]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max)
    }
}

#[test]
fn explicit_updates_conserve_momentum_exactly_in_a_cell() {
    let mut r = Rng::new(0x5eed_1234);
    for trial in 0..200 {
        let nf = 1 + trial % 16;
        let mut c = Cell::random(&mut r, nf);
        let (p0, scale) = c.momentum();
        // Any τ, even far beyond the stability limit: conservation is algebraic.
        let tau = r.log(1e-8, 1.0);
        c.step(tau);
        let (p1, _) = c.momentum();
        for d in 0..3 {
            let rel = (p1[d] - p0[d]).abs() / scale;
            // Σm|v| after the step can be ≫ before (unstable τ); compare to the larger scale.
            let rel = rel.min((p1[d] - p0[d]).abs() / c.momentum().1);
            assert!(
                rel < 1e-13,
                "trial {trial}, N = {nf}, τ = {tau:e}: drift {rel:e}"
            );
        }
    }
}

#[test]
fn explicit_rate_for_one_fraction_is_the_relative_velocity_decay_rate() {
    // N = 1: Λ = (1+ε)/t, the inverse of the Laibe & Price / Phantom t_s = t/(1+ε).
    for (eps, t) in [(0.01f64, 1e-3f64), (1.0, 0.1), (100.0, 1e-6)] {
        let l = explicit_rate(&[eps], &[1.0 / t]);
        assert!(((l * t / (1.0 + eps)) - 1.0).abs() < 1e-14);
    }
}

/// At τ = 0.9/Λ every β_k and Σ_k ε_k β_k are ≤ 0.9, so each new velocity is a convex
/// combination of old ones: the largest deviation from the (conserved) barycentric velocity can
/// never grow.
#[test]
fn the_limit_is_stable_and_the_naive_tau_below_t_stop_is_not() {
    let mut r = Rng::new(77);
    for trial in 0..100 {
        let nf = 1 + trial % 16;
        let mut c = Cell::random(&mut r, nf);
        let tau = 0.9 / c.rate();
        let s0 = c.spread();
        let mut last = s0;
        for _ in 0..2000 {
            c.step(tau);
            let s = c.spread();
            assert!(
                s <= last * (1.0 + 1e-12) + 1e-14 * s0,
                "trial {trial}: spread grew {last:e} → {s:e}"
            );
            last = s;
        }
        // t_stop spans six decades, so the slowest fractions barely move in 2000 steps; the
        // fastest relax: the spread must have fallen.
        assert!(last < s0, "trial {trial}: spread {s0:e} → {last:e}");
    }
    // One fraction, ε = 10, τ = 0.9 t: the relative velocity is multiplied by 1 − 0.9·11 = −8.9
    // per step, so "τ < t_stop" in the ρ_d/K convention of method.md §1.1 is not a stable limit.
    let mut c = Cell {
        gas: vec![(1.0, [0.0; 3])],
        dust: vec![vec![(10.0, [1.0, 0.0, 0.0])]],
        t_stop: vec![1e-3],
    };
    let s0 = c.spread();
    for _ in 0..10 {
        c.step(0.9e-3);
    }
    assert!(c.spread() > 1e8 * s0, "{:e}", c.spread());
}

#[test]
fn a_run_obeys_the_limit_and_relaxes_as_forward_euler() {
    // Uniform box, one fraction, ε = 1, t = 1e-3: Λ = 2000, τ = 4.5e-4 whatever time.dt asks;
    // the slip is multiplied by 1 − τΛ = 0.1 each step, the barycentric velocity is exact.
    let t_lim = 0.9e-3 / 2.0;
    let (s, st) = run_scene(
        "dustybox",
        &[
            "drag.method=\"explicit\"",
            "dust.fractions=[{eps=1.0, t_stop=1e-3}]",
            "dustybox.u_dust=[1.0]",
            &format!("time.t_end={}", 8.0 * t_lim),
            "time.output_dt=",
            "time.dt=0.01",
        ],
    );
    assert_eq!(s.drag_method, "explicit");
    assert_eq!(s.steps, 8, "dt_max {:e}", s.dt_max);
    assert_eq!(s.drag_limited_steps, 8);
    assert!(s.dt_max <= t_lim * (1.0 + 1e-12), "{:e}", s.dt_max);
    assert!(s.pipeline.iter().any(|p| p.contains("explicit drag")));
    assert!(s.pipeline.iter().all(|p| !p.contains("IDIC")));
    let slip = 1e-8; // 0.1^8 × the initial slip of 1
    for (u, v) in st.dust[0].v.iter().zip(&st.gas.ph.v) {
        assert!(
            ((v[0] - u[0]) / slip + 1.0).abs() < 1e-6,
            "slip {:e}",
            u[0] - v[0]
        );
        assert!((0.5 * (u[0] + v[0]) - 0.5).abs() < 1e-14);
    }
    assert!(s.conservation.momentum_drift_relative < 1e-14);
}

#[test]
fn explicit_converges_at_first_order_and_idic_steps_ignore_t_stop() {
    // The four-fraction box (t_stop 0.1 … 1): the limit 0.9/Λ ≈ 0.067 is above these τ.
    let errs: Vec<f64> = [0.02, 0.01, 0.005]
        .iter()
        .map(|dt| {
            let (s, _) = run_scene(
                "dustybox",
                &["drag.method=\"explicit\"", &format!("time.dt={dt}")],
            );
            assert_eq!(s.drag_limited_steps, 0);
            ["v_g", "u_d0", "u_d1", "u_d2", "u_d3"]
                .iter()
                .map(|f| final_error(&s, 0, f).l1)
                .fold(0.0, f64::max)
        })
        .collect();
    for w in errs.windows(2) {
        let p = order(w[0], w[1], 2.0);
        assert!((0.9..1.1).contains(&p), "order {p} from {errs:?}");
    }
    let (s, _) = run_scene(
        "dustybox",
        &[
            "dust.fractions=[{eps=1.0, t_stop=1e-9}]",
            "dustybox.u_dust=[1.0]",
        ],
    );
    assert_eq!(s.steps, 100, "IDIC: τ = time.dt whatever t_stop");
    assert_eq!(s.drag_limited_steps, 0);
}

#[test]
fn explicit_drag_without_dust_is_refused_naming_the_key() {
    let text = std::fs::read_to_string(config("dustywave")).unwrap();
    let file = std::path::Path::new("dustywave.toml");
    let sets = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let e = dustsph::scene::parse(&text, file, &sets(&["drag.method=\"explicit\"", "dust="]))
        .unwrap_err();
    assert_eq!(e.key.as_deref(), Some("drag.method"), "{e}");
    let e = dustsph::scene::parse(&text, file, &sets(&["drag.method=\"rk4\""])).unwrap_err();
    assert_eq!(e.key.as_deref(), Some("drag.method"), "{e}");
    let e = dustsph::scene::parse(&text, file, &sets(&["drag.safety=0.5"])).unwrap_err();
    assert_eq!(e.key.as_deref(), Some("drag.safety"), "{e}");
}
