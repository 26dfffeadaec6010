//! The GPU step, run on the CPU through the emulated launcher (the very kernel code the PTX
//! entry points call), against the rayon CPU engine: every array of every phase, step by step.
//!
//! Both backends call the same bodies in the same summation order, so the comparison is exact
//! (bit for bit) — the f64 parity bound the GPU path must meet with its deterministic sums.
mod common;

use dustsph::engine::cpu::CpuEngine;
use dustsph::engine::gpu::{Emulated, GpuEngine};
use dustsph::engine::{dt_limits, Physics};
use dustsph::particles::{Phase, State};
use dustsph::scene::Scene;
use dustsph::setup;

fn physics(scene: &Scene) -> (Physics, State) {
    let su = setup::build(scene).unwrap();
    (Physics::from_scene(scene, su.h, su.domain), su.state)
}

fn same_phase(what: &str, a: &Phase, b: &Phase, check_rho: bool) {
    assert_eq!(a.id, b.id, "{what}: particle order");
    assert_eq!(a.x, b.x, "{what}: positions");
    assert_eq!(a.v, b.v, "{what}: velocities");
    assert_eq!(a.m, b.m, "{what}: masses");
    if check_rho {
        assert_eq!(a.rho, b.rho, "{what}: densities");
    }
    assert_eq!(a.fixed, b.fixed, "{what}: fixed flags");
}

fn same_state(step: u64, a: &State, b: &State, dust_rho: bool) {
    same_phase(&format!("step {step} gas"), &a.gas.ph, &b.gas.ph, true);
    assert_eq!(a.gas.p, b.gas.p, "step {step}: gas pressure");
    assert_eq!(a.gas.c, b.gas.c, "step {step}: gas sound speed");
    assert_eq!(a.gas.e, b.gas.e, "step {step}: gas energy");
    for (k, (da, db)) in a.dust.iter().zip(&b.dust).enumerate() {
        same_phase(&format!("step {step} dust {k}"), da, db, dust_rho);
    }
}

/// `steps` steps of a scene on both backends with the CPU's time step; states compared
/// after set-up and after every step, stopping times at the end.
fn parity(name: &str, sets: &[&str], steps: u64) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = dustsph::scene::load(&common::config(name), &sets).unwrap();
    let scene = &loaded.scene;
    let (phys, mut s_cpu) = physics(scene);
    let mut s_gpu = s_cpu.clone();
    let mut cpu = CpuEngine::new(phys.clone(), &mut s_cpu).unwrap();
    let mut gpu = GpuEngine::new(phys.clone(), &mut s_gpu, Emulated).unwrap();
    let dust_rho = cpu.pipe.dust_density_each_step;
    same_state(0, &s_cpu, &s_gpu, dust_rho);
    for step in 1..=steps {
        let fc = cpu.forces(&s_cpu);
        let fg = gpu.forces().unwrap();
        assert_eq!(
            fc.vsig_max, fg.vsig_max,
            "{name} step {step}: max signal speed"
        );
        assert_eq!(fc.acc_max, fg.acc_max, "{name} step {step}: max |A|");
        let (cfl, force) = dt_limits(phys.h, &fc);
        let dt = scene
            .time
            .dt
            .unwrap_or_else(|| scene.time.cfl.unwrap() * cfl.min(force));
        cpu.advance(&mut s_cpu, &fc, dt).unwrap();
        gpu.advance(&mut s_gpu, dt).unwrap();
        gpu.sync(&mut s_gpu).unwrap();
        assert_eq!(s_cpu.t, s_gpu.t);
        same_state(step, &s_cpu, &s_gpu, dust_rho);
    }
    let tc = cpu.dust_stopping_times(&mut s_cpu);
    let tg = gpu.dust_stopping_times(&mut s_gpu).unwrap();
    assert_eq!(tc, tg, "{name}: dust stopping times");
    for (k, (a, b)) in s_cpu.dust.iter().zip(&s_gpu.dust).enumerate() {
        assert_eq!(a.rho, b.rho, "{name}: dust {k} output densities");
    }
}

#[test]
fn dustybox_gpu_kernels_match_cpu_bit_for_bit() {
    parity("dustybox", &[], 20);
}

#[test]
fn dustywave_gpu_kernels_match_cpu_bit_for_bit() {
    parity("dustywave", &["sph.n=64"], 20);
}

#[test]
fn adiabatic_constant_k_wave_gpu_kernels_match_cpu() {
    // Energy equation, dust density every step (constant K), old position update.
    parity(
        "dustywave",
        &[
            "sph.n=64",
            "gas.eos=adiabatic",
            "gas.cs=",
            "gas.gamma=1.4",
            "gas.p=1.0",
            "dust.law=constant_k",
            "dust.fractions=[{eps=1.0, k=5.0}, {eps=0.5, k=50.0}]",
            "time.position_update=old",
        ],
        15,
    );
}

#[test]
fn dustyshock_gpu_kernels_match_cpu_bit_for_bit() {
    // Walls (fixed particles), artificial viscosity, drag heating.
    parity("dustyshock", &["sph.n=200"], 20);
}

#[test]
fn small_ball_gpu_kernels_match_cpu_bit_for_bit() {
    // 3D, open boundaries (the grid follows the particles), Epstein drag.
    parity("dusty_ball", &["sph.n=6", "sph.h=0.3"], 8);
}
