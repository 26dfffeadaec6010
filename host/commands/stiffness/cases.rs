//! The matrix's cases: waves, boxes, the Phantom wave and the ball from configs/ with overrides; the slab.
use super::{Case, Kind, WAVE_DT};
use crate::scene;

const WAVE: &str = include_str!("../../../configs/dustywave.toml");
const BOX: &str = include_str!("../../../configs/dustybox.toml");
const BALL: &str = include_str!("../../../configs/dusty_ball.toml");
const PHANTOM_WAVE: &str = include_str!("../../../configs/dustywave_phantom.toml");

fn fractions(eps: &[f64], t_stop: &[f64]) -> String {
    let f: Vec<String> = eps
        .iter()
        .zip(t_stop)
        .map(|(e, t)| format!("{{eps={e:e}, t_stop={t:e}}}"))
        .collect();
    format!("dust.fractions=[{}]", f.join(", "))
}

fn wave(eps: &[f64], t_stop: &[f64]) -> Kind {
    Kind::Scene {
        base: WAVE,
        sets: vec![
            "time.cfl=".into(),
            format!("time.dt={WAVE_DT}"),
            "time.output_dt=".into(),
            "sph.n=64".into(),
            "dustywave.mode=\"sine\"".into(),
            fractions(eps, t_stop),
        ],
    }
}

fn dusty_box(eps: &[f64], t_stop: &[f64], v0: f64, u0: f64) -> Kind {
    let u: Vec<String> = eps.iter().map(|_| format!("{u0:e}")).collect();
    Kind::Scene {
        base: BOX,
        sets: vec![
            "time.t_end=0.5".into(),
            "time.output_dt=".into(),
            fractions(eps, t_stop),
            format!("dustybox.v_gas={v0:e}"),
            format!("dustybox.u_dust=[{}]", u.join(", ")),
        ],
    }
}

/// t_stop spanning six decades, 1e-7 … 1e-1, log-spaced (one fraction: 1e-4).
fn six_decades(n: usize) -> Vec<f64> {
    if n == 1 {
        return vec![1e-4];
    }
    (0..n)
        .map(|k| 10f64.powf(-7.0 + 6.0 * k as f64 / (n - 1) as f64))
        .collect()
}

/// The full matrix (`reduced` marks the CI subset).
pub fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    let mut add = |group, name: String, reduced, kind| {
        v.push(Case {
            group,
            name,
            reduced,
            kind,
        })
    };
    for r in [1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6] {
        add(
            "τ/t_stop",
            format!("wave N=1, ε=1, τ/t_stop={}", scene::num(r)),
            [1e-3, 1.0, 1e6].contains(&r),
            wave(&[1.0], &[WAVE_DT / r]),
        );
    }
    for e in [1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2] {
        for r in [1.0, 1e4] {
            add(
                "dust-to-gas ratio",
                format!("wave N=1, ε={}, τ/t_stop={}", scene::num(e), scene::num(r)),
                (e == 1e-3 || e == 1e2) && r == 1e4,
                wave(&[e], &[WAVE_DT / r]),
            );
        }
    }
    for n in [1usize, 2, 4, 8, 16] {
        let t = six_decades(n);
        let eps = vec![1.0 / n as f64; n];
        let span = if n == 1 {
            "t_stop=1e-4".to_string()
        } else {
            "t_stop 1e-7…1e-1".to_string()
        };
        add(
            "fractions",
            format!("wave N={n}, Σε=1, {span}"),
            n == 16,
            wave(&eps, &t),
        );
        add(
            "fractions",
            format!("box N={n}, Σε=1, {span}, slip 1"),
            n == 16,
            dusty_box(&eps, &t, 0.0, 1.0),
        );
    }
    add(
        "fractions",
        "box N=16, Σε=100, t_stop 1e-7…1e-1, slip 1".into(),
        false,
        dusty_box(&[100.0 / 16.0; 16], &six_decades(16), 0.0, 1.0),
    );
    add(
        "fractions",
        "box 2D N=16, Σε=1, t_stop 1e-7…1e-1, slip 1".into(),
        false,
        {
            let mut k = dusty_box(&[1.0 / 16.0; 16], &six_decades(16), 0.0, 1.0);
            if let Kind::Scene { sets, .. } = &mut k {
                sets.extend(["scene.dim=2".to_string(), "sph.n=32".to_string()]);
            }
            k
        },
    );
    add(
        "τ/t_stop",
        "wave N=1, ε=1, t_stop=1e-9 (τ/t_stop ≈ 5e6), n=256, CFL 0.3".into(),
        false,
        Kind::Scene {
            base: WAVE,
            sets: vec![
                "time.output_dt=".into(),
                "dustywave.mode=\"sine\"".into(),
                fractions(&[1.0], &[1e-9]),
            ],
        },
    );
    add(
        "velocities",
        "box N=1, ε=1, t_stop=1e-6, all at rest".into(),
        true,
        dusty_box(&[1.0], &[1e-6], 0.0, 0.0),
    );
    add(
        "velocities",
        "box N=1, ε=1, t_stop=1e-6, no slip, v=u=1e3".into(),
        false,
        dusty_box(&[1.0], &[1e-6], 1e3, 1e3),
    );
    add(
        "velocities",
        "box N=1, ε=1, t_stop=1e-6, slip 1e6".into(),
        true,
        dusty_box(&[1.0], &[1e-6], 0.0, 1e6),
    );
    add(
        "velocities",
        "box N=4, ε=100, t_stop=1e-8, slip 2e8 (v=−1e8, u=1e8)".into(),
        false,
        dusty_box(&[25.0; 4], &[1e-8; 4], -1e8, 1e8),
    );
    // Dust off the gas at ≈57 neighbours (3D, hfact 1.2), with the kernel coupling
    // (docs/method.md §K): the regime the nearest cell cannot couple.
    let placed = |mut k: Kind, shift: &str| {
        if let Kind::Scene { sets, .. } = &mut k {
            sets.extend([
                "scene.dim=3".to_string(),
                "sph.n=16".to_string(),
                "sph.hfact=1.2".to_string(),
                format!("dustybox.dust_shift={shift}"),
                "idic.coupling=\"kernel\"".to_string(),
            ]);
        }
        k
    };
    add(
        "placement (3D, ≈57 nb)",
        "box 3D N=4, Σε=1, t_stop 1e-8…1e-5 (τ/t_stop ≤ 1e6), dust offset 0.5 Δ, kernel coupling"
            .into(),
        true,
        placed(
            dusty_box(&[0.25; 4], &[1e-8, 1e-7, 1e-6, 1e-5], 0.0, 1.0),
            "0.5",
        ),
    );
    add(
        "placement (3D, ≈57 nb)",
        "box 3D N=16, Σε=1, t_stop 1e-7…1e-1, dust offset 0.25 Δ, kernel coupling".into(),
        false,
        placed(
            dusty_box(&[1.0 / 16.0; 16], &six_decades(16), 0.0, 1.0),
            "0.25",
        ),
    );
    add(
        "placement (3D, ≈57 nb)",
        "box 3D N=1, ε=100, t_stop=1e-8, slip 1e6, dust offset 0.5 Δ, kernel coupling".into(),
        false,
        placed(dusty_box(&[100.0], &[1e-8], 0.0, 1e6), "0.5"),
    );
    // The same off any lattice: a relaxed glass and jittered lattices (docs/method.md §K,
    // "Disordered particles"), every phase drawn on its own.
    let disordered = |k: Kind, arrangement: &str| {
        let mut k = placed(k, "0");
        if let Kind::Scene { sets, .. } = &mut k {
            sets.push(arrangement.to_string());
        }
        k
    };
    add(
        "disordered (3D, ≈57 nb)",
        "box 3D N=4, Σε=1, t_stop 1e-8…1e-5 (τ/t_stop ≤ 1e6), glass, kernel coupling".into(),
        true,
        disordered(
            dusty_box(&[0.25; 4], &[1e-8, 1e-7, 1e-6, 1e-5], 0.0, 1.0),
            "dustybox.lattice=\"glass\"",
        ),
    );
    add(
        "disordered (3D, ≈57 nb)",
        "box 3D N=16, Σε=1, t_stop 1e-7…1e-1, jitter 0.3, kernel coupling".into(),
        false,
        disordered(
            dusty_box(&[1.0 / 16.0; 16], &six_decades(16), 0.0, 1.0),
            "dustybox.jitter=0.3",
        ),
    );
    add(
        "disordered (3D, ≈57 nb)",
        "box 3D N=16, Σε=100, t_stop 1e-7…1e-1, glass, kernel coupling".into(),
        false,
        disordered(
            dusty_box(&[100.0 / 16.0; 16], &six_decades(16), 0.0, 1.0),
            "dustybox.lattice=\"glass\"",
        ),
    );
    add(
        "disordered (3D, ≈57 nb)",
        "box 3D N=1, ε=100, t_stop=1e-8, slip 1e6, jitter 0.2, kernel coupling".into(),
        false,
        disordered(
            dusty_box(&[100.0], &[1e-8], 0.0, 1e6),
            "dustybox.jitter=0.2",
        ),
    );
    for k in ["1e5", "1e7"] {
        add(
            "placement (3D, ≈57 nb)",
            format!(
                "Phantom wave 3D n=32, K={k} (τ/t_stop ≈ {}), dust offset 0.5 Δ, kernel coupling",
                if k == "1e5" { "1e3" } else { "1e5" }
            ),
            false,
            Kind::Scene {
                base: PHANTOM_WAVE,
                sets: vec![
                    "sph.n=32".into(),
                    "time.output_dt=".into(),
                    "dustywave.dust_shift=0.5".into(),
                    "idic.coupling=\"kernel\"".into(),
                    format!("dust.fractions.0.k={k}"),
                ],
            },
        );
    }
    add(
        "cells",
        "slab into vacuum: dust-only, gas-only and one-particle cells; particles leave the initial domain".into(),
        true,
        Kind::Slab,
    );
    add(
        "cells",
        "3D ball into vacuum (n=8, h=2Δ): Epstein t_stop, particles leave the initial domain"
            .into(),
        false,
        Kind::Scene {
            base: BALL,
            sets: vec![
                "sph.n=8".into(),
                "sph.h=".into(),
                "sph.hfact=2.0".into(),
                "time.output_dt=".into(),
            ],
        },
    );
    v
}
