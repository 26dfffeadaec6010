//! The GPU path without a GPU.
//!
//! 1. The GPU step, run on the CPU through the emulated launcher (the very kernel code the PTX
//!    entry points call), against the rayon CPU engine: every array of every phase after every
//!    step, on every scene kind. Both backends call the same bodies in the same summation order
//!    (the GPU's cell sums are segmented over cell-sorted particles, not atomic), so the
//!    comparison is exact, bit for bit — the f64 bound the real GPU must also meet.
//! 2. The PTX entry points take exactly the argument bytes the host passes: the parameter size
//!    of every `.entry` equals the size of its host-side argument struct.
mod common;
use dustsph::engine::backend::DeviceChoice;
use dustsph::engine::gpu::{self, launch::KERNELS};
use dustsph::parity::{compare, compare_scenes, compare_tables, CASES};
use dustsph_device::threads as th;
use std::path::PathBuf;

fn case(i: usize) {
    let (label, file, sets, steps) = CASES[i];
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
    let loaded = dustsph::scene::load(&path, &sets).unwrap();
    let p = compare(&loaded, steps, DeviceChoice::Emulate).unwrap();
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
fn dustybox_gpu_kernels_match_cpu_bit_for_bit() {
    case(0);
}

#[test]
fn dustywave_gpu_kernels_match_cpu_bit_for_bit() {
    case(1);
}

#[test]
fn adiabatic_constant_k_wave_gpu_kernels_match_cpu_bit_for_bit() {
    case(2);
}

#[test]
fn dustyshock_gpu_kernels_match_cpu_bit_for_bit() {
    case(3);
}

#[test]
fn small_ball_gpu_kernels_match_cpu_bit_for_bit() {
    case(4);
}

#[test]
fn kernel_coupling_box_3d_offset_with_external_matches_cpu_bit_for_bit() {
    case(5);
}

#[test]
fn kernel_coupling_wave_offset_matches_cpu_bit_for_bit() {
    case(6);
}

#[test]
fn kernel_coupling_adiabatic_constant_k_wave_matches_cpu_bit_for_bit() {
    case(7);
}

#[test]
fn kernel_coupling_shock_matches_cpu_bit_for_bit() {
    case(8);
}

#[test]
fn kernel_coupling_ball_matches_cpu_bit_for_bit() {
    case(9);
}

#[test]
fn kernel_coupling_settle_matches_cpu_bit_for_bit() {
    case(10);
}

#[test]
fn variable_h_iad_phantom_wave_matches_cpu_bit_for_bit() {
    case(11);
}

#[test]
fn variable_h_adiabatic_wave_with_heating_matches_cpu_bit_for_bit() {
    case(12);
}

#[test]
fn iad_small_ball_matches_cpu_bit_for_bit() {
    case(13);
}

#[test]
fn leapfrog_phantom_wave_as_shipped_matches_cpu_bit_for_bit() {
    case(14);
}

#[test]
fn leapfrog_shock_with_heating_matches_cpu_bit_for_bit() {
    case(15);
}

#[test]
fn leapfrog_kernel_coupling_box_matches_cpu_bit_for_bit() {
    case(16);
}

#[test]
fn explicit_drag_wave_matches_cpu_bit_for_bit() {
    case(17);
}

#[test]
fn explicit_drag_leapfrog_shock_matches_cpu_bit_for_bit() {
    case(18);
}

#[test]
fn continuity_density_wave_matches_cpu_bit_for_bit() {
    case(19);
}

#[test]
fn kernel_coupling_variable_h_phantom_wave_matches_cpu_bit_for_bit() {
    case(20);
}

#[test]
fn kernel_coupling_heating_shock_matches_cpu_bit_for_bit() {
    case(21);
}

#[test]
fn kernel_coupling_old_update_wave_matches_cpu_bit_for_bit() {
    case(22);
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
fn ptx_entry_points_take_the_host_argument_structs() {
    if gpu::PTX.is_empty() {
        assert!(
            std::env::var_os("DUSTSPH_REQUIRE_PTX").is_none(),
            "no PTX in this build ({}), and DUSTSPH_REQUIRE_PTX is set",
            gpu::PTX_NOTE
        );
        eprintln!("skipped: no PTX in this build ({})", gpu::PTX_NOTE);
        return;
    }
    use std::mem::size_of;
    let want: &[(&str, usize)] = &[
        ("dustsph_bounds", size_of::<th::BoundsArgs>()),
        ("dustsph_keys", size_of::<th::KeysArgs>()),
        ("dustsph_scan_sums", size_of::<th::ScanArgs>()),
        ("dustsph_scan_totals", size_of::<th::ScanArgs>()),
        ("dustsph_scan_chunks", size_of::<th::ScanArgs>()),
        ("dustsph_scatter", size_of::<th::ScatterArgs>()),
        ("dustsph_sort_segments", size_of::<th::SegmentArgs>()),
        ("dustsph_gather_v3", size_of::<th::GatherArgs<[f64; 3]>>()),
        ("dustsph_gather_f64", size_of::<th::GatherArgs<f64>>()),
        ("dustsph_gather_u64", size_of::<th::GatherArgs<u64>>()),
        ("dustsph_gather_u8", size_of::<th::GatherArgs<u8>>()),
        ("dustsph_density", size_of::<th::DensityArgs>()),
        ("dustsph_eos", size_of::<th::EosArgs>()),
        ("dustsph_forces", size_of::<th::ForcesArgs>()),
        ("dustsph_union_flags", size_of::<th::UnionArgs>()),
        ("dustsph_union_keys", size_of::<th::UnionArgs>()),
        ("dustsph_solve_h", size_of::<th::HSolveArgs>()),
        ("dustsph_force_prep", size_of::<th::PrepArgs>()),
        ("dustsph_iad_matrix", size_of::<th::IadArgs>()),
        ("dustsph_max_of", size_of::<th::MaxArgs>()),
        ("dustsph_copy_v3", size_of::<th::CopyArgs<[f64; 3]>>()),
        ("dustsph_copy_f64", size_of::<th::CopyArgs<f64>>()),
        ("dustsph_density_continuity", size_of::<th::DensityArgs>()),
        ("dustsph_explicit_limit", size_of::<th::LimitArgs>()),
        ("dustsph_cell_step", size_of::<th::CellArgs>()),
        ("dustsph_gas_kick", size_of::<th::KickArgs>()),
        ("dustsph_dust_kick", size_of::<th::KickArgs>()),
        ("dustsph_heat", size_of::<th::HeatArgs>()),
        ("dustsph_drift", size_of::<th::DriftArgs>()),
        ("dustsph_energy", size_of::<th::EnergyArgs>()),
        ("dustsph_check", size_of::<th::CheckArgs>()),
        ("dustsph_dust_accel", size_of::<th::DustAccelArgs>()),
        ("dustsph_coupling_norm", size_of::<th::NormArgs>()),
        ("dustsph_coupling_solve", size_of::<th::CoupleArgs>()),
        ("dustsph_coupling_return", size_of::<th::ReturnArgs>()),
        ("dustsph_coupling_tstop", size_of::<th::ReturnArgs>()),
        ("dustsph_coupling_heat", size_of::<th::CouplingHeatArgs>()),
        (
            "dustsph_coupling_scatter",
            size_of::<th::ScatterDepositArgs>(),
        ),
        (
            "dustsph_coupling_solve_sums",
            size_of::<th::ScatterDepositArgs>(),
        ),
    ];
    let got = entry_param_sizes(gpu::PTX);
    assert_eq!(got.len(), KERNELS.len(), "entry points in the PTX: {got:?}");
    for (name, size) in want {
        assert!(
            KERNELS.contains(name),
            "{name} is not in the launcher's list"
        );
        let g = got.iter().find(|(n, _)| n == name);
        assert_eq!(
            g.map(|g| g.1),
            Some(*size),
            "{name}: PTX parameter bytes vs host struct"
        );
    }
    assert!(
        !gpu::PTX.contains(".extern"),
        "unresolved externs in the PTX"
    );
}

/// The design card's atomicAdd form of the kernel coupling's deposits (`idic.deposit =
/// "scatter"`) against the gather: the same sums in the hardware's order, so equal to
/// round-off, not bit for bit. (In the uniform box the pressure forces are themselves
/// round-off, so their maximum is compared on the wave only.)
#[test]
fn kernel_coupling_scatter_deposits_match_the_gather_to_round_off() {
    for case in [5, 6] {
        let (label, file, sets, steps) = CASES[case];
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
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
            .filter(|f| f.max_relative >= 1e-12 && !(case == 5 && f.field == "max |A|"))
            .collect();
        assert!(bad.is_empty(), "{label}, scatter deposits: {bad:?}");
        assert!(
            !p.bitwise(),
            "{label}: the scatter is bit-identical to the gather (is it running?)"
        );
    }
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
