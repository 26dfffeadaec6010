//! The step on its launchers, without a GPU.
//!
//! 1. Determinism: every scene kind and option stepped on one thread and on four threads of
//!    the rayon launcher (the thread functions the PTX entry points call), every array of
//!    every phase compared after every step, bit for bit. The kernels' contract — no thread
//!    writes another's element except through atomics whose order cannot change a result — is
//!    what a GPU relies on too. (The CUDA launcher against this reference is `dustsph parity
//!    --device cuda`, run by scripts/gpu-check on a GPU.)
//! 2. The PTX's entry points are the kernel table's, each taking the bytes of its host-side
//!    argument struct.
//! 3. Forms that must not change the step: sparse cell tables, neighbour lists, the kernel
//!    coupling's scatter deposits (to round-off); f32 against f64; the device-memory estimate.
mod common;
use dustsph::commands::parity::{compare, compare_scenes, compare_tables, CASES};
use dustsph::launch;
use dustsph::step::backend::DeviceChoice;
use dustsph_device::kernel_table;
use std::path::PathBuf;

fn case(i: usize) {
    let (label, file, sets, steps) = CASES[i];
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
    let loaded = dustsph::scene::load(&path, &sets).unwrap();
    // Four threads even on a one-core runner: the comparison is of the kernels' contract,
    // not of the machine.
    let four = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    let p = four
        .install(|| compare(&loaded, steps, DeviceChoice::Cpu))
        .unwrap();
    assert_eq!(p.steps, steps);
    for f in &p.fields {
        assert!(
            f.bitwise,
            "{label}: {} differs (max relative {:.3e})",
            f.field, f.max_relative
        );
    }
    assert!(p.fields.len() > 10, "{label}: too few fields compared");
}

#[test]
fn dustybox_steps_bit_identically_on_1_and_4_threads() {
    case(0);
}

#[test]
fn dustywave_steps_bit_identically_on_1_and_4_threads() {
    case(1);
}

#[test]
fn adiabatic_constant_k_wave_steps_bit_identically_on_1_and_4_threads() {
    case(2);
}

#[test]
fn dustyshock_steps_bit_identically_on_1_and_4_threads() {
    case(3);
}

#[test]
fn small_ball_steps_bit_identically_on_1_and_4_threads() {
    case(4);
}

#[test]
fn kernel_coupling_box_3d_offset_with_external_steps_bit_identically_on_1_and_4_threads() {
    case(5);
}

#[test]
fn kernel_coupling_wave_offset_steps_bit_identically_on_1_and_4_threads() {
    case(6);
}

#[test]
fn kernel_coupling_adiabatic_constant_k_wave_steps_bit_identically_on_1_and_4_threads() {
    case(7);
}

#[test]
fn kernel_coupling_shock_steps_bit_identically_on_1_and_4_threads() {
    case(8);
}

#[test]
fn kernel_coupling_ball_steps_bit_identically_on_1_and_4_threads() {
    case(9);
}

#[test]
fn kernel_coupling_settle_steps_bit_identically_on_1_and_4_threads() {
    case(10);
}

#[test]
fn variable_h_iad_phantom_wave_steps_bit_identically_on_1_and_4_threads() {
    case(11);
}

#[test]
fn variable_h_adiabatic_wave_with_heating_steps_bit_identically_on_1_and_4_threads() {
    case(12);
}

#[test]
fn iad_small_ball_steps_bit_identically_on_1_and_4_threads() {
    case(13);
}

#[test]
fn leapfrog_phantom_wave_as_shipped_steps_bit_identically_on_1_and_4_threads() {
    case(14);
}

#[test]
fn leapfrog_shock_with_heating_steps_bit_identically_on_1_and_4_threads() {
    case(15);
}

#[test]
fn leapfrog_kernel_coupling_box_steps_bit_identically_on_1_and_4_threads() {
    case(16);
}

#[test]
fn explicit_drag_wave_steps_bit_identically_on_1_and_4_threads() {
    case(17);
}

#[test]
fn explicit_drag_leapfrog_shock_steps_bit_identically_on_1_and_4_threads() {
    case(18);
}

#[test]
fn continuity_density_wave_steps_bit_identically_on_1_and_4_threads() {
    case(19);
}

#[test]
fn kernel_coupling_variable_h_phantom_wave_steps_bit_identically_on_1_and_4_threads() {
    case(20);
}

#[test]
fn kernel_coupling_heating_shock_steps_bit_identically_on_1_and_4_threads() {
    case(21);
}

#[test]
fn kernel_coupling_old_update_wave_steps_bit_identically_on_1_and_4_threads() {
    case(22);
}

#[test]
fn damped_dispersion_disc_steps_bit_identically_on_1_and_4_threads() {
    case(23);
}

#[test]
fn disc_viscosity_disc_steps_bit_identically_on_1_and_4_threads() {
    case(24);
}

#[test]
fn the_3d_disc_in_physical_units_steps_bit_identically_on_1_and_4_threads() {
    case(25);
}

/// Byte size of the single parameter of each entry point in the PTX.
fn entry_param_sizes(ptx: &str) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    let mut lines = ptx.lines();
    while let Some(l) = lines.next() {
        if let Some(rest) = l.trim().strip_prefix(".visible .entry ") {
            let name = rest.trim_end_matches('(').to_string();
            let param = lines.next().unwrap_or("");
            let size = param
                .rsplit('[')
                .next()
                .and_then(|s| {
                    s.trim_end_matches(|c: char| !c.is_ascii_digit())
                        .parse()
                        .ok()
                })
                .unwrap_or(0);
            out.push((name, size));
        }
    }
    out
}

#[test]
fn ptx_entry_points_are_the_kernel_table_with_its_argument_structs() {
    if launch::PTX.is_empty() {
        assert!(
            std::env::var_os("DUSTSPH_REQUIRE_PTX").is_none(),
            "no PTX in this build ({}), and DUSTSPH_REQUIRE_PTX is set",
            launch::PTX_NOTE
        );
        eprintln!("skipped: no PTX in this build ({})", launch::PTX_NOTE);
        return;
    }
    // Every entry point of the PTX is a kernel of the table, and every kernel of the table is
    // in the PTX taking the bytes of the host's argument struct.
    let got = entry_param_sizes(launch::PTX);
    let mut names: Vec<&str> = got.iter().map(|g| g.0.as_str()).collect();
    let mut want: Vec<&str> = kernel_table::NAMES.to_vec();
    names.sort();
    want.sort();
    assert_eq!(
        names, want,
        "entry points in the PTX against the kernel table"
    );
    for (name, bytes) in kernel_table::ARG_BYTES {
        let size = got.iter().find(|(g, _)| g == name).map(|g| g.1);
        assert_eq!(
            size,
            Some(*bytes),
            "{name}: PTX parameter bytes vs host struct"
        );
    }
    assert!(
        !launch::PTX.contains(".extern"),
        "unresolved externs in the PTX"
    );
}

/// The design card's atomicAdd form of the kernel coupling's deposits (`idic.deposit =
/// "scatter"`) against the gather: the same sums in the hardware's order (the gather's rows
/// are in ascending particle order, which a scatter by threads in order may reproduce bit for
/// bit), so equal to round-off. In f32 the scatter sums in f64 and the gather in f32: there
/// they must differ (to f32 round-off of the wave's small amplitude), which shows the scatter
/// ran. (In the uniform box the pressure forces are
/// themselves round-off, so their maximum is compared on the wave only.)
#[test]
fn kernel_coupling_scatter_deposits_match_the_gather_to_round_off() {
    for case in [5, 6] {
        for (prec, bound) in [("f64", 1e-12), ("f32", 1e-2)] {
            let (label, file, sets, steps) = CASES[case];
            let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            sets.push(format!("numerics.precision=\"{prec}\""));
            let mut scatter = sets.clone();
            scatter.push("idic.deposit=scatter".into());
            let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
            let gather = dustsph::scene::load(&path, &sets).unwrap();
            let scatter = dustsph::scene::load(&path, &scatter).unwrap();
            let p = compare_scenes(&gather, &scatter, steps, DeviceChoice::Cpu, false).unwrap();
            assert!(p.fields.len() > 10);
            let bad: Vec<_> = p
                .fields
                .iter()
                .filter(|f| f.max_relative >= bound && !(case == 5 && f.field == "max |A|"))
                .collect();
            assert!(
                bad.is_empty(),
                "{label} ({prec}), scatter deposits: {bad:?}"
            );
            if prec == "f32" {
                assert!(
                    !p.bitwise(),
                    "{label}: the f32 gather is bit-identical to the f64-summed scatter (is it \
                     running?)"
                );
            }
        }
    }
}

/// The kernel coupling's deposit rows made in chunks of particles (the CPU's form) and by a
/// thread per particle with atomic cursors and a sort of each row (the GPU's form): the same
/// rows, so the same step bit for bit, in f64 and f32, on every kernel-coupling case.
#[test]
fn deposit_rows_in_chunks_equal_the_atomic_form() {
    let mut compared = 0;
    for (label, file, sets, steps) in CASES {
        if !sets.iter().any(|s| s.contains("coupling=kernel")) {
            continue;
        }
        for prec in ["f64", "f32"] {
            let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            sets.push(format!("numerics.precision=\"{prec}\""));
            let mut atomic = sets.clone();
            sets.push("numerics.deposit_rows=\"chunks\"".into());
            atomic.push("numerics.deposit_rows=\"atomic\"".into());
            let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
            let chunks = dustsph::scene::load(&path, &sets).unwrap();
            let atomic = dustsph::scene::load(&path, &atomic).unwrap();
            let p = compare_scenes(&chunks, &atomic, (*steps).min(6), DeviceChoice::Cpu, false)
                .unwrap();
            for f in &p.fields {
                assert!(
                    f.bitwise,
                    "{label} ({prec}), atomic deposit rows: {} differs (max relative {:.3e})",
                    f.field, f.max_relative
                );
            }
            compared += 1;
        }
    }
    assert!(
        compared >= 10,
        "only {compared} kernel-coupling cases compared"
    );
}

/// A cloud too spread out for dense cell tables (a few particles flung far away) gets sorted
/// cell lists and binary searches instead: the same step, bit for bit, on every kind of scene.
#[test]
fn sparse_cell_tables_give_the_same_step() {
    for i in [1, 3, 4, 5, 14, 17, 21] {
        let (label, file, sets, steps) = CASES[i];
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
        let loaded = dustsph::scene::load(&path, &sets).unwrap();
        let p = compare_tables(&loaded, steps.min(8), DeviceChoice::Cpu, true).unwrap();
        for f in &p.fields {
            assert!(
                f.bitwise,
                "{label}, sparse tables: {} differs (max relative {:.3e})",
                f.field, f.max_relative
            );
        }
    }
}

/// The f32 kernels (`numerics.precision = "f32"`) on every scene and option: four threads
/// against one, bit for bit (the same f32 operations in the same order; the PTX has no
/// contraction and IEEE-rounded div/sqrt, so a GPU must meet this too).
#[test]
fn f32_kernels_step_bit_identically_on_1_and_4_threads_on_every_case() {
    let four = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    for (label, file, sets, steps) in CASES {
        let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        sets.push("numerics.precision=\"f32\"".into());
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
        let loaded = dustsph::scene::load(&path, &sets).unwrap();
        let p = four
            .install(|| compare(&loaded, (*steps).min(8), DeviceChoice::Cpu))
            .unwrap();
        assert!(p.device.contains("f32"), "{label}: ran on {}", p.device);
        for f in &p.fields {
            assert!(
                f.bitwise,
                "{label}, f32: {} differs (max relative {:.3e})",
                f.field, f.max_relative
            );
        }
    }
}

/// The f32 step against the f64 step from the same particles: different (it really runs in
/// f32), and within single-precision round-off after a few steps, fields matched by particle
/// id. Bounds (measured, with ≈5× margin or more): 1e-5 of each field's scale; the Phantom
/// wave's velocities 1e-2 and largest acceleration 5e-2 (measured 1.8e-3 and 8.9e-3), as their
/// signal is 1e-4 of the sound speed and the pressure whose f32 round-off it carries
/// (docs/accuracy.md); the uniform box's max |A| is itself round-off of zero and is not
/// compared. The ball is the kernel-coupling one: with the nearest cell a dust particle
/// sitting on its gas particle can land in the next cell at round-off and lose its drag, a
/// discrete jump (up to half the velocity scale) that is the nearest cell's, not f32's.
#[test]
fn f32_step_follows_the_f64_step_to_single_precision() {
    for i in [0, 3, 9, 11, 14] {
        let (label, file, sets, steps) = CASES[i];
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let mut sets32 = sets.clone();
        sets32.push("numerics.precision=\"f32\"".into());
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
        let f64_scene = dustsph::scene::load(&path, &sets).unwrap();
        let f32_scene = dustsph::scene::load(&path, &sets32).unwrap();
        let p = compare_scenes(
            &f64_scene,
            &f32_scene,
            steps.min(8),
            DeviceChoice::Cpu,
            false,
        )
        .unwrap();
        assert!(
            !p.bitwise(),
            "{label}: f32 equals f64 bit for bit (is it running?)"
        );
        let wave = label.contains("Phantom wave");
        for f in &p.fields {
            // A particle can change cell at round-off; fields are matched by id.
            if (i == 0 && f.field == "max |A|") || f.field.ends_with("id (order)") {
                continue;
            }
            let bound = match (wave, f.field.as_str()) {
                (true, "max |A|") => 5e-2,
                (true, v) if v.contains(" v[") => 1e-2,
                _ => 1e-5,
            };
            assert!(
                f.max_relative < bound,
                "{label}: f32 {} differs from f64 by {:.3e} (bound {bound:e})",
                f.field,
                f.max_relative
            );
        }
    }
}

/// The device-memory estimate that `--device cuda` checks before it allocates
/// (`dustsph::step::engine::device_bytes_estimate`: `DEVICE_BYTES_PER_PARTICLE` per particle
/// and, with the kernel coupling, `COUPLING_BYTES_PER_PAIR` per estimated pair; plus
/// `LIST_BYTES_PER_GAS_PARTICLE` with neighbour lists) bounds what the engine allocates, on
/// every case, after a few steps (buffers grown included), in both precisions, without lists
/// (CUDA's default) and with them. The rayon launcher allocates the very buffers a GPU does.
#[test]
fn device_memory_estimate_bounds_what_the_engine_allocates() {
    use dustsph::sim::Simulation;
    use dustsph::step::engine;
    let mut worst = [0.0f64; 2];
    for (label, file, sets, _) in CASES {
        for (k, prec) in ["f64", "f32"].iter().enumerate() {
            for lists in ["off", "on"] {
                let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
                sets.push(format!("numerics.precision=\"{prec}\""));
                sets.push(format!("numerics.neighbour_list=\"{lists}\""));
                let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
                let loaded = dustsph::scene::load(&path, &sets).unwrap();
                let (mut sim, _) = Simulation::of_scene(&loaded.scene, DeviceChoice::Cpu).unwrap();
                let state = &sim.state;
                let ng = state.gas.ph.x.len();
                let n = ng + state.dust.iter().map(|d| d.x.len()).sum::<usize>();
                let pairs = engine::coupling_pairs_estimate(&sim.phys, state);
                let mut est = engine::device_bytes_estimate(&sim.phys, state, k == 1);
                if lists == "on" {
                    est += engine::LIST_BYTES_PER_GAS_PARTICLE * ng as f64;
                }
                let time = &loaded.scene.time;
                for _ in 0..3 {
                    sim.step(time.t_end).unwrap();
                }
                let bytes = sim.local_engine().unwrap().device_bytes() as f64;
                eprintln!(
                    "{label} ({prec}, lists {lists}): {:.0} B per particle ({n} particles, \
                     {pairs:.0} pairs estimated), {:.2} of the estimate",
                    bytes / n as f64,
                    bytes / est
                );
                assert!(
                    bytes <= est,
                    "{label} ({prec}, lists {lists}): {bytes:.0} B above the estimate {est:.0}"
                );
                if lists == "off" && pairs == 0.0 {
                    worst[k] = worst[k].max(bytes / n as f64);
                }
            }
        }
    }
    eprintln!(
        "largest without pairs: f64 {:.0} B, f32 {:.0} B per particle",
        worst[0], worst[1]
    );
    for (k, (w, est)) in worst
        .iter()
        .zip(engine::DEVICE_BYTES_PER_PARTICLE)
        .enumerate()
    {
        assert!(
            *w <= est,
            "precision {k}: {w:.0} B per particle above the estimate {est}"
        );
    }
}

/// Neighbour lists (`numerics.neighbour_list`, on by default on the CPU) replay the cell
/// walk's pairs in its order: every case gives the same step with and without them, bit for
/// bit, in f64 and f32.
#[test]
fn neighbour_lists_give_the_same_step() {
    for (label, file, sets, steps) in CASES {
        for prec in ["f64", "f32"] {
            let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            sets.push(format!("numerics.precision=\"{prec}\""));
            let mut on = sets.clone();
            sets.push("numerics.neighbour_list=\"off\"".into());
            on.push("numerics.neighbour_list=\"on\"".into());
            let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
            let off = dustsph::scene::load(&path, &sets).unwrap();
            let on = dustsph::scene::load(&path, &on).unwrap();
            let p = compare_scenes(&off, &on, (*steps).min(8), DeviceChoice::Cpu, false).unwrap();
            for f in &p.fields {
                assert!(
                    f.bitwise,
                    "{label} ({prec}), lists: {} differs (max relative {:.3e})",
                    f.field, f.max_relative
                );
            }
        }
    }
}
