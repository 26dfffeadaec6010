//! The step is assembled from the scene, and the unbounded grid never drops a particle.
mod common;
use common::*;
use dustsph::particles::{Gas, Phase, State};
use dustsph::step::backend::{Backend, DeviceChoice};
use dustsph::step::Physics;
use dustsph_device::drag::StoppingLaw;
use dustsph_device::eos::Eos;

#[test]
fn no_dust_means_no_drag_pass_and_isothermal_means_no_energy() {
    let (s, st) = run_scene("dustyshock", &["dust="]);
    assert!(st.dust.is_empty());
    assert!(
        s.pipeline.iter().all(|p| !p.contains("IDIC")),
        "{:?}",
        s.pipeline
    );
    // Pure-gas Sod against the exact Riemann solution (measured L1(ρ) 7.1e-3 at n = 800).
    assert!(final_error(&s, 0, "rho_g").l1 < 1.5e-2);
    let (s, st) = run_scene("dustywave", &[]);
    assert!(
        st.gas.e.is_none(),
        "isothermal gas must not allocate an energy field"
    );
    assert!(
        s.pipeline.iter().all(|p| !p.contains("energy")),
        "{:?}",
        s.pipeline
    );
    assert!(
        s.pipeline.iter().all(|p| !p.contains("viscosity")),
        "{:?}",
        s.pipeline
    );
    assert!(s.pipeline.iter().any(|p| p.contains("IDIC")));
    assert!(
        s.pipeline.iter().all(|p| !p.contains("dust density")),
        "constant t_stop needs no dust density per step"
    );
    let (s, _) = run_scene(
        "dustywave",
        &[
            "dust.law=\"constant_k\"",
            "dust.fractions=[{eps=1.0, k=10.0}]",
        ],
    );
    assert!(
        s.pipeline.iter().any(|p| p.contains("dust density")),
        "{:?}",
        s.pipeline
    );
    let (s, st) = run_scene("dustyshock", &[]);
    assert!(st.gas.e.is_some());
    assert!(
        s.pipeline.iter().any(|p| p.contains("viscosity"))
            && s.pipeline.iter().any(|p| p.contains("drag heating"))
    );
}

#[test]
fn a_slab_expanding_into_vacuum_keeps_every_particle() {
    // Gas + dust slab at rest in [-0.5, 0.5] with pressure and vacuum around: it spreads far
    // beyond its initial extent; the grid must follow it.
    let n = 200;
    let dx = 1.0 / n as f64;
    let x: Vec<[f64; 3]> = (0..n)
        .map(|i| [-0.5 + (i as f64 + 0.5) * dx, 0.0, 0.0])
        .collect();
    let phase = |m: f64, id0: u64| Phase {
        x: x.clone(),
        v: vec![[0.0; 3]; n],
        m: vec![m; n],
        rho: vec![1.0; n],
        id: (id0..id0 + n as u64).collect(),
        fixed: None,
    };
    let mut st = State {
        t: 0.0,
        step: 0,
        gas: Gas {
            ph: phase(dx, 0),
            p: vec![0.0; n],
            c: vec![0.0; n],
            e: Some(vec![2.5; n]),
            h: None,
            omega: None,
            closing_forces: None,
        },
        dust: vec![phase(0.5 * dx, n as u64)],
    };
    let h = 4.0 * dx;
    let phys = Physics::open_1d(
        h,
        Eos::Adiabatic { gamma: 1.4 },
        vec![StoppingLaw::Epstein {
            s_rho: 1e-3,
            stokes: 0.0,
        }],
    );
    let mut eng = Backend::new(DeviceChoice::Cpu, phys, &mut st).unwrap();
    let mut pscale: f64 = 0.0;
    for _ in 0..300 {
        eng.forces().unwrap();
        eng.advance(&mut st, 2e-3).unwrap();
        eng.sync(&mut st).unwrap();
        pscale = pscale.max(st.momentum_scale());
    }
    // The drag pass ran (the stage the step recorded), not merely was planned.
    assert!(
        eng.timers()
            .entries()
            .iter()
            .any(|e| e.0.starts_with("IDIC drag")),
        "{:?}",
        eng.timers().entries()
    );
    assert_eq!(st.gas.ph.len(), n);
    assert_eq!(st.dust[0].len(), n);
    let mut ids: Vec<u64> = st.gas.ph.id.iter().chain(&st.dust[0].id).copied().collect();
    ids.sort();
    assert_eq!(
        ids,
        (0..2 * n as u64).collect::<Vec<_>>(),
        "every particle is still there once"
    );
    let xmax = st.gas.ph.x.iter().map(|x| x[0].abs()).fold(0.0, f64::max);
    assert!(
        xmax > 0.7,
        "the slab must have spread well past its initial edge (max |x| = {xmax})"
    );
    let p = st.total_momentum();
    assert!(
        p[0].abs() < 1e-12 * pscale,
        "momentum {p:?} vs scale {pscale}"
    );
}

#[test]
fn dust_in_cells_without_gas_is_ballistic_not_dragged_to_rest() {
    // Gas at rest near the origin; a dust cloud far away moving at u = 1 with a tiny t_stop.
    // method.md §3.5: the reference code drags such dust towards zero velocity; here it must
    // coast, exactly.
    let n = 100;
    let dx = 0.01;
    let gx: Vec<[f64; 3]> = (0..n).map(|i| [(i as f64 + 0.5) * dx, 0.0, 0.0]).collect();
    let dxs: Vec<[f64; 3]> = (0..n)
        .map(|i| [5.0 + (i as f64 + 0.5) * dx, 0.0, 0.0])
        .collect();
    let mut st = State {
        t: 0.0,
        step: 0,
        gas: Gas {
            ph: Phase {
                x: gx,
                v: vec![[0.0; 3]; n],
                m: vec![dx; n],
                rho: vec![1.0; n],
                id: (0..n as u64).collect(),
                fixed: None,
            },
            p: vec![0.0; n],
            c: vec![0.0; n],
            e: None,
            h: None,
            omega: None,
            closing_forces: None,
        },
        dust: vec![Phase {
            x: dxs.clone(),
            v: vec![[1.0, 0.0, 0.0]; n],
            m: vec![dx; n],
            rho: vec![1.0; n],
            id: (n as u64..2 * n as u64).collect(),
            fixed: None,
        }],
    };
    let h = 2.0 * dx;
    let phys = Physics::open_1d(
        h,
        Eos::Isothermal { cs: 1.0 },
        vec![StoppingLaw::ConstantTime { t_stop: 1e-9 }],
    );
    let mut eng = Backend::new(DeviceChoice::Cpu, phys, &mut st).unwrap();
    for _ in 0..10 {
        eng.forces().unwrap();
        eng.advance(&mut st, 1e-3).unwrap();
    }
    eng.sync(&mut st).unwrap();
    for (d, x0) in st.dust[0].v.iter().zip(st.dust[0].x.iter()) {
        assert_eq!(d[0], 1.0, "uncoupled dust must keep its velocity exactly");
        assert!(x0[0] > 5.0);
    }
    let mut xs: Vec<f64> = st.dust[0].x.iter().map(|x| x[0]).collect();
    xs.sort_by(f64::total_cmp);
    for (x, x0) in xs.iter().zip(&dxs) {
        assert!(
            (x - (x0[0] + 0.01)).abs() < 1e-12,
            "ballistic drift {x} vs {}",
            x0[0] + 0.01
        );
    }
}

/// Issue 13: a grid that cannot be built (a particle flung absurdly far) stops naming the step,
/// the time and the particle, as the bad-value check does.
#[test]
fn a_grid_that_cannot_be_built_names_step_time_and_particle() {
    let loaded = dustsph::scene::load(
        &config("dustybox"),
        &[
            "scene.dim=3".to_string(),
            "sph.n=8".to_string(),
            "sph.hfact=1.2".to_string(),
        ],
    )
    .unwrap();
    let su = dustsph::setup::build(&loaded.scene).unwrap();
    let phys = Physics::from_scene(&loaded.scene, su.h, su.domain);
    let mut st = su.state;
    // The box is periodic: the far particle goes into an open 3D ball-like domain instead.
    let mut phys = phys;
    phys.domain.periodic = [None; 3];
    let far_id = st.gas.ph.id[7];
    st.gas.ph.x[7] = [3e19, -3e19, 1e19];
    let e = match Backend::new(DeviceChoice::Cpu, phys, &mut st) {
        Ok(_) => panic!("a grid over 1e19 with cells of 0.05 was built"),
        Err(e) => e.to_string(),
    };
    assert!(
        e.contains("step 0, t = 0") && e.contains(&format!("gas particle id {far_id}")),
        "{e}"
    );
}
