use super::*;
use crate::io::shared::CHUNK_ROWS;
use hdf5::filters::Filter;
use hdf5::types::{FixedAscii, FloatSize, IntSize, TypeDescriptor, VarLenUnicode};
use hdf5::File;
use std::fs;
use std::path::PathBuf;

const SCENE: &str = "# Schéma de test — poussière\n[gas]\nname = \"gaz ρ₀\"\ngamma = 1.4\n\n\
                     [[dust]]\nsize = \"1 µm\"  # ✓ ünïcödé\n";
const MODEL: &str = "[gas]\neos = \"adiabatic\"\ngamma = 1.4 # γ\n";

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn bits3(v: &[[f64; 3]]) -> Vec<[u64; 3]> {
    v.iter()
        .map(|p| [p[0].to_bits(), p[1].to_bits(), p[2].to_bits()])
        .collect()
}

/// Owned arrays behind a PhaseView, with awkward values to make "bit-exact" mean something.
struct Phase {
    x: Vec<[f64; 3]>,
    v: Vec<[f64; 3]>,
    m: Vec<f64>,
    rho: Vec<f64>,
    id: Vec<u64>,
    e: Vec<f64>,
    p: Vec<f64>,
    t: Vec<f64>,
}

impl Phase {
    fn new(n: usize, seed: u64) -> Self {
        let f = |i: usize, k: u64| {
            let s = (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (seed * 31 + k);
            // Irrational-looking mantissas; occasional sign flips.
            (s % 1_000_003) as f64 / 7.0 * if s & 4 == 0 { -1.0 } else { 1.0 }
        };
        let mut ph = Phase {
            x: (0..n).map(|i| [f(i, 1), f(i, 2), 0.0]).collect(),
            v: (0..n).map(|i| [f(i, 3), f(i, 4), f(i, 5)]).collect(),
            m: (0..n).map(|i| f(i, 6).abs() * 1e-30).collect(),
            rho: (0..n).map(|i| f(i, 7).abs()).collect(),
            id: (0..n).map(|i| seed << 40 | i as u64).collect(),
            e: (0..n).map(|i| f(i, 8)).collect(),
            p: (0..n).map(|i| f(i, 9)).collect(),
            t: (0..n).map(|i| f(i, 10).abs()).collect(),
        };
        if n >= 3 {
            ph.x[0][2] = -0.0;
            ph.v[1][0] = f64::MIN_POSITIVE / 8.0; // subnormal
            ph.t[2] = f64::INFINITY;
            ph.id[1] = u64::MAX;
        }
        ph
    }

    fn view(&self, h: f64, gas: bool, t_stop: bool) -> PhaseView<'_> {
        PhaseView {
            x: &self.x,
            v: &self.v,
            m: &self.m,
            rho: &self.rho,
            h,
            h_each: None,
            id: &self.id,
            e: gas.then_some(&self.e[..]),
            p: gas.then_some(&self.p[..]),
            t_stop: t_stop.then_some(&self.t[..]),
        }
    }
}

fn snap<'a>(gas: Option<PhaseView<'a>>, dust: Vec<PhaseView<'a>>) -> SnapshotView<'a> {
    SnapshotView {
        time: 0.125 + f64::EPSILON,
        dim: 2,
        periodic: [None; 3],
        pad: 0.25,
        scene_text: SCENE,
        scene_model: MODEL,
        source: SceneSource::default(),
        gas,
        dust,
    }
}

fn names_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// Positions come back through the file's box-relative frame: exact up to one rounding
/// at the scale of the offset.
fn assert_close3(got: &[[f64; 3]], want: &[[f64; 3]], offset: [f64; 3]) {
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(want) {
        for k in 0..3 {
            let tol = 4.0 * f64::EPSILON * (w[k].abs() + offset[k].abs());
            assert!((g[k] - w[k]).abs() <= tol, "{g:?} vs {w:?}");
        }
    }
}

fn assert_phase_eq(got: &PhaseData, want: &Phase, h: f64, gas: bool, offset: [f64; 3]) {
    assert_close3(&got.x, &want.x, offset);
    assert_eq!(bits3(&got.v), bits3(&want.v));
    assert_eq!(bits(&got.m), bits(&want.m));
    assert_eq!(bits(&got.rho), bits(&want.rho));
    assert_eq!(bits(&got.h), bits(&vec![h; want.x.len()]));
    assert_eq!(got.id, want.id);
    if gas {
        assert_eq!(bits(got.e.as_ref().unwrap()), bits(&want.e));
        assert_eq!(bits(got.p.as_ref().unwrap()), bits(&want.p));
        assert!(got.t_stop.is_none() && got.fraction.is_none());
    }
}

#[test]
fn round_trip_gas_and_two_dust_fractions_in_the_box_frame() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("snapshot_0003.h5");
    let (g, d0, d1) = (Phase::new(6, 1), Phase::new(3, 2), Phase::new(4, 3));
    let s = snap(
        Some(g.view(0.03, true, false)),
        vec![d0.view(0.05, false, true), d1.view(0.07, false, true)],
    );
    write_snapshot(&path, &s).unwrap();
    let r = read_snapshot(&path).unwrap();

    assert_eq!(r.time.to_bits(), s.time.to_bits());
    assert_eq!(r.dim, 2);
    // An open axis is the particles' extent plus the pad on both sides; z (unused in 2D)
    // is 2 pads wide around 0.
    for k in 0..2 {
        let xs = [&g, &d0, &d1]
            .iter()
            .flat_map(|p| p.x.iter().map(|x| x[k]))
            .collect::<Vec<_>>();
        let (lo, hi) = xs
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| {
                (a.min(y), b.max(y))
            });
        assert_eq!(r.offset[k], lo - 0.25);
        assert_eq!(r.box_size[k], hi - lo + 0.5);
    }
    assert_eq!((r.offset[2], r.box_size[2]), (-0.25, 0.5));
    // What GADGET readers see: every stored coordinate inside [0, BoxSize).
    let f = hdf5::File::open(&path).unwrap();
    for grp in ["PartType0", "PartType3"] {
        let c: Vec<f64> = f
            .dataset(&format!("{grp}/Coordinates"))
            .unwrap()
            .read_raw()
            .unwrap();
        for (i, v) in c.iter().enumerate() {
            assert!(
                *v >= 0.0 && *v < r.box_size[i % 3],
                "{grp} coordinate {v} outside the box"
            );
        }
        let sl: Vec<f64> = f
            .dataset(&format!("{grp}/SmoothingLength"))
            .unwrap()
            .read_raw()
            .unwrap();
        assert!(
            sl.iter().all(|&h| h == 0.06 || h == 0.1 || h == 0.14),
            "{sl:?}"
        );
    }
    assert_eq!(r.scene_text, SCENE);
    assert_eq!(r.num_part, [6, 0, 0, 7, 0, 0]);
    assert_phase_eq(r.gas.as_ref().unwrap(), &g, 0.03, true, r.offset);

    let dust = r.dust.unwrap();
    let cat = |f: fn(&Phase) -> Vec<f64>| [f(&d0), f(&d1)].concat();
    let x: Vec<[f64; 3]> = [d0.x.clone(), d1.x.clone()].concat();
    let v: Vec<[f64; 3]> = [d0.v.clone(), d1.v.clone()].concat();
    assert_close3(&dust.x, &x, r.offset);
    assert_eq!(bits3(&dust.v), bits3(&v));
    assert_eq!(bits(&dust.m), bits(&cat(|p| p.m.clone())));
    assert_eq!(bits(&dust.rho), bits(&cat(|p| p.rho.clone())));
    assert_eq!(
        bits(&dust.h),
        bits(
            &[0.05; 3]
                .iter()
                .chain(&[0.07; 4])
                .copied()
                .collect::<Vec<_>>()
        )
    );
    assert_eq!(dust.id, [d0.id.clone(), d1.id.clone()].concat());
    assert_eq!(
        bits(dust.t_stop.as_ref().unwrap()),
        bits(&cat(|p| p.t.clone()))
    );
    assert!(dust.t_stop.as_ref().unwrap()[2].is_infinite());
    assert_eq!(dust.fraction.unwrap(), vec![0, 0, 0, 1, 1, 1, 1]);
    assert!(dust.e.is_none() && dust.p.is_none());
}

#[test]
fn header_attributes_have_the_documented_values_and_types() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("snapshot_0000.h5");
    let (g, d0, d1) = (Phase::new(5, 1), Phase::new(2, 2), Phase::new(3, 3));
    let s = snap(
        Some(g.view(0.1, true, false)),
        vec![d0.view(0.1, false, true), d1.view(0.1, false, false)],
    );
    write_snapshot(&path, &s).unwrap();

    let f = File::open(&path).unwrap();
    let h = f.group("Header").unwrap();
    let desc = |n: &str| h.attr(n).unwrap().dtype().unwrap().to_descriptor().unwrap();
    let shape = |n: &str| h.attr(n).unwrap().shape();
    use TypeDescriptor as T;

    for n in ["Time", "SmoothingLengthPerH", "BoxSize"] {
        assert_eq!(desc(n), T::Float(FloatSize::U8), "{n}");
        assert_eq!(shape(n), Vec::<usize>::new(), "{n}");
    }
    let time: f64 = h.attr("Time").unwrap().read_scalar().unwrap();
    assert_eq!(time.to_bits(), s.time.to_bits());
    let per_h: f64 = h
        .attr("SmoothingLengthPerH")
        .unwrap()
        .read_scalar()
        .unwrap();
    assert_eq!(per_h, 2.0);
    // One BoxSize (yt reads one value), the largest extent; the rest per axis.
    for n in ["BoxSizePerAxis", "CoordinateOffset"] {
        assert_eq!(desc(n), T::Float(FloatSize::U8), "{n}");
        assert_eq!(shape(n), vec![3], "{n}");
    }
    let frame = Frame::of(&s);
    let bs: Vec<f64> = h.attr("BoxSizePerAxis").unwrap().read_raw().unwrap();
    let off: Vec<f64> = h.attr("CoordinateOffset").unwrap().read_raw().unwrap();
    assert_eq!((&bs, off), (&frame.size.to_vec(), frame.offset.to_vec()));
    let one: f64 = h.attr("BoxSize").unwrap().read_scalar().unwrap();
    assert_eq!(one, bs.iter().fold(0.0f64, |a, &b| a.max(b)));

    for n in ["NumPart_ThisFile", "NumPart_Total"] {
        assert_eq!(desc(n), T::Unsigned(IntSize::U8), "{n}");
        assert_eq!(shape(n), vec![6], "{n}");
        let v: Vec<u64> = h.attr(n).unwrap().read_raw().unwrap();
        assert_eq!(v, vec![5, 0, 0, 5, 0, 0], "{n}");
    }
    assert_eq!(desc("MassTable"), T::Float(FloatSize::U8));
    let mt: Vec<f64> = h.attr("MassTable").unwrap().read_raw().unwrap();
    assert_eq!(bits(&mt), vec![0u64; 6]);

    for (n, want) in [("NumFilesPerSnapshot", 1), ("Dimension", 2)] {
        assert_eq!(desc(n), T::Integer(IntSize::U4), "{n}");
        assert_eq!(shape(n), Vec::<usize>::new(), "{n}");
        let v: i32 = h.attr(n).unwrap().read_scalar().unwrap();
        assert_eq!(v, want, "{n}");
    }
    assert_eq!(desc("Code"), T::FixedAscii(7));
    assert_eq!(shape("Code"), Vec::<usize>::new());
    let code: FixedAscii<7> = h.attr("Code").unwrap().read_scalar().unwrap();
    assert_eq!(code.as_str(), "dustsph");
    assert_eq!(desc("Scene"), T::VarLenUnicode);
    assert_eq!(shape("Scene"), Vec::<usize>::new());
    let scene: VarLenUnicode = h.attr("Scene").unwrap().read_scalar().unwrap();
    assert_eq!(scene.as_str(), SCENE);
    assert_eq!(desc("SceneModel"), T::VarLenUnicode);
    let model: VarLenUnicode = h.attr("SceneModel").unwrap().read_scalar().unwrap();
    assert_eq!(model.as_str(), MODEL);
    assert_eq!(
        read_header(&path).unwrap().scene_model.as_deref(),
        Some(MODEL)
    );
    // The yt-compatibility extras.
    for (n, want) in [
        ("Redshift", 0.0),
        ("Omega0", 0.0),
        ("OmegaLambda", 0.0),
        ("HubbleParam", 1.0),
    ] {
        let v: f64 = h.attr(n).unwrap().read_scalar().unwrap();
        assert_eq!(v, want, "{n}");
    }
    let hw: Vec<u32> = h
        .attr("NumPart_Total_HighWord")
        .unwrap()
        .read_raw()
        .unwrap();
    assert_eq!(hw, vec![0; 6]);
}

#[test]
fn datasets_have_documented_names_types_shapes_and_filters() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("snapshot_0001.h5");
    let (g, d0, d1) = (Phase::new(5, 1), Phase::new(2, 2), Phase::new(3, 3));
    let s = snap(
        Some(g.view(0.1, true, false)),
        vec![d0.view(0.1, false, true), d1.view(0.1, false, true)],
    );
    write_snapshot(&path, &s).unwrap();
    let f = File::open(&path).unwrap();
    use TypeDescriptor as T;
    let f64t = T::Float(FloatSize::U8);

    let mut gas = f.group(GAS_GROUP).unwrap().member_names().unwrap();
    gas.sort();
    let want_gas = [
        "Coordinates",
        "Density",
        "InternalEnergy",
        "Masses",
        "ParticleIDs",
        "Pressure",
        "SmoothingLength",
        "Velocities",
    ];
    assert_eq!(gas, want_gas);
    let mut dust = f.group(DUST_GROUP).unwrap().member_names().unwrap();
    dust.sort();
    let want_dust = [
        "Coordinates",
        "Density",
        "FractionIndex",
        "Masses",
        "ParticleIDs",
        "SmoothingLength",
        "StoppingTime",
        "Velocities",
    ];
    assert_eq!(dust, want_dust);

    for (group, n, names) in [
        (GAS_GROUP, 5usize, &want_gas[..]),
        (DUST_GROUP, 5, &want_dust[..]),
    ] {
        for name in names {
            let ds = f.dataset(&format!("{group}/{name}")).unwrap();
            let (shape, ty) = match *name {
                "Coordinates" | "Velocities" => (vec![n, 3], f64t.clone()),
                "ParticleIDs" => (vec![n], T::Unsigned(IntSize::U8)),
                "FractionIndex" => (vec![n], T::Unsigned(IntSize::U4)),
                _ => (vec![n], f64t.clone()),
            };
            assert_eq!(ds.shape(), shape, "{group}/{name}");
            assert_eq!(
                ds.dtype().unwrap().to_descriptor().unwrap(),
                ty,
                "{group}/{name}"
            );
            assert!(ds.is_chunked(), "{group}/{name}");
            assert_eq!(
                ds.filters(),
                vec![Filter::Shuffle, Filter::Deflate(DEFLATE_LEVEL)],
                "{group}/{name}"
            );
        }
    }
}

#[test]
fn compression_actually_shrinks_redundant_data() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.h5");
    let n = 100_000; // several chunks
    let x = vec![[1.0, 2.0, 0.0]; n];
    let m = vec![1e-3; n];
    let id: Vec<u64> = (0..n as u64).collect();
    let gas = PhaseView {
        x: &x,
        v: &x,
        m: &m,
        rho: &m,
        h: 0.1,
        h_each: None,
        id: &id,
        e: None,
        p: None,
        t_stop: None,
    };
    write_snapshot(&path, &snap(Some(gas), vec![])).unwrap();
    let f = File::open(&path).unwrap();
    let ds = f.dataset("PartType0/Masses").unwrap();
    assert!(
        ds.storage_size() < (n * 8 / 20) as u64,
        "{}",
        ds.storage_size()
    );
    assert_eq!(ds.chunk(), Some(vec![CHUNK_ROWS]));
    assert_eq!(
        f.dataset("PartType0/Coordinates").unwrap().chunk(),
        Some(vec![CHUNK_ROWS, 3])
    );
    let r = read_snapshot(&path).unwrap();
    assert_eq!(r.gas.unwrap().id, id);
}

#[test]
fn optional_datasets_are_omitted_when_absent() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.h5");
    let (g, d0) = (Phase::new(3, 1), Phase::new(3, 2));
    let mut gv = g.view(0.1, false, false);
    gv.e = Some(&g.e);
    write_snapshot(&path, &snap(Some(gv), vec![d0.view(0.2, false, false)])).unwrap();
    let f = File::open(&path).unwrap();
    assert!(f.link_exists("PartType0/InternalEnergy"));
    assert!(!f.link_exists("PartType0/Pressure"));
    assert!(!f.link_exists("PartType3/StoppingTime"));
    assert!(f.link_exists("PartType3/FractionIndex"));
    let r = read_snapshot(&path).unwrap();
    let gas = r.gas.unwrap();
    assert_eq!(bits(&gas.e.unwrap()), bits(&g.e));
    assert!(gas.p.is_none());
    assert!(r.dust.unwrap().t_stop.is_none());
}

#[test]
fn fractions_without_stopping_time_are_filled_with_nan() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.h5");
    let (d0, d1) = (Phase::new(2, 1), Phase::new(3, 2));
    let s = snap(
        None,
        vec![d0.view(0.1, false, false), d1.view(0.1, false, true)],
    );
    write_snapshot(&path, &s).unwrap();
    let t = read_snapshot(&path).unwrap().dust.unwrap().t_stop.unwrap();
    assert!(t[..2].iter().all(|x| x.is_nan()));
    assert_eq!(bits(&t[2..]), bits(&d1.t));
}

#[test]
fn gas_only_and_dust_only_snapshots_omit_the_other_group() {
    let dir = tempfile::tempdir().unwrap();
    let (g, d) = (Phase::new(3, 1), Phase::new(3, 2));

    let p1 = dir.path().join("gas.h5");
    write_snapshot(&p1, &snap(Some(g.view(0.1, true, false)), vec![])).unwrap();
    let r = read_snapshot(&p1).unwrap();
    assert!(r.gas.is_some() && r.dust.is_none());
    assert_eq!(r.num_part, [3, 0, 0, 0, 0, 0]);
    assert!(!File::open(&p1).unwrap().link_exists(DUST_GROUP));

    let p2 = dir.path().join("dust.h5");
    write_snapshot(&p2, &snap(None, vec![d.view(0.1, false, true)])).unwrap();
    let r = read_snapshot(&p2).unwrap();
    assert!(r.gas.is_none());
    assert_eq!(r.num_part, [0, 0, 0, 3, 0, 0]);
    assert_eq!(r.dust.unwrap().fraction.unwrap(), vec![0, 0, 0]);
    assert!(!File::open(&p2).unwrap().link_exists(GAS_GROUP));
}

#[test]
fn empty_phases_and_empty_fractions_work() {
    let dir = tempfile::tempdir().unwrap();
    let (empty, d1) = (Phase::new(0, 0), Phase::new(4, 2));

    // An empty fraction between non-empty ones keeps the indices of the others.
    let p1 = dir.path().join("a.h5");
    let s = snap(
        Some(empty.view(0.1, true, false)),
        vec![
            empty.view(0.1, false, true),
            d1.view(0.2, false, true),
            empty.view(0.3, false, true),
        ],
    );
    write_snapshot(&p1, &s).unwrap();
    let r = read_snapshot(&p1).unwrap();
    assert_eq!(r.num_part, [0, 0, 0, 4, 0, 0]);
    let gas = r.gas.unwrap();
    assert!(gas.x.is_empty() && gas.e.unwrap().is_empty());
    let dust = r.dust.unwrap();
    assert_eq!(dust.fraction.unwrap(), vec![1, 1, 1, 1]);
    assert_eq!(bits(&dust.t_stop.unwrap()), bits(&d1.t));

    // Only empty datasets: stored contiguous and unfiltered, still readable.
    let p2 = dir.path().join("b.h5");
    write_snapshot(&p2, &snap(None, vec![empty.view(0.1, false, true)])).unwrap();
    let f = File::open(&p2).unwrap();
    let c = f.dataset("PartType3/Coordinates").unwrap();
    assert_eq!(c.shape(), vec![0, 3]);
    assert!(!c.is_chunked());
    assert!(c.filters().is_empty());
    let r = read_snapshot(&p2).unwrap();
    assert_eq!(r.num_part, [0; 6]);
    let dust = r.dust.unwrap();
    assert!(dust.x.is_empty() && dust.t_stop.unwrap().is_empty());
    assert!(dust.fraction.unwrap().is_empty());
}

#[test]
fn success_leaves_only_the_final_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("snapshot_0003.h5");
    // A stale temporary from a crashed run must not get in the way.
    fs::write(dir.path().join(".snapshot_0003.h5.tmp"), b"garbage").unwrap();
    let g = Phase::new(3, 1);
    write_snapshot(&path, &snap(Some(g.view(0.1, true, false)), vec![])).unwrap();
    assert_eq!(names_in(dir.path()), vec!["snapshot_0003.h5"]);
    assert!(path.is_file());
}

#[test]
fn overwriting_replaces_the_previous_snapshot() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("snapshot_0000.h5");
    let (a, b) = (Phase::new(3, 1), Phase::new(5, 2));
    write_snapshot(&path, &snap(Some(a.view(0.1, true, false)), vec![])).unwrap();
    write_snapshot(&path, &snap(None, vec![b.view(0.1, false, true)])).unwrap();
    let r = read_snapshot(&path).unwrap();
    assert!(r.gas.is_none());
    assert_eq!(r.num_part, [0, 0, 0, 5, 0, 0]);
    assert_eq!(names_in(dir.path()), vec!["snapshot_0000.h5"]);
}

#[test]
fn missing_directory_is_an_error_naming_it_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no_such_dir");
    let path = missing.join("snapshot_0000.h5");
    let g = Phase::new(3, 1);
    let err = write_snapshot(&path, &snap(Some(g.view(0.1, true, false)), vec![])).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains(&*missing.to_string_lossy()), "{msg}");
    assert!(matches!(err, IoError::Io { .. }), "{err:?}");
    assert!(!missing.exists());
    assert!(names_in(dir.path()).is_empty());
}

#[test]
fn inconsistent_lengths_are_rejected_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("snapshot_0000.h5");
    let g = Phase::new(3, 1);
    let mut gv = g.view(0.1, true, false);
    gv.m = &g.m[..2];
    let err = write_snapshot(&path, &snap(Some(gv), vec![])).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains(&*path.to_string_lossy()) && msg.contains("`m`"),
        "{msg}"
    );

    let d = Phase::new(3, 2);
    let mut dv = d.view(0.1, false, true);
    dv.t_stop = Some(&d.t[..1]);
    let err = write_snapshot(&path, &snap(None, vec![d.view(0.1, false, true), dv])).unwrap_err();
    assert!(err.to_string().contains("dust fraction 1"), "{err}");

    let mut s = snap(None, vec![]);
    s.dim = 4;
    assert!(write_snapshot(&path, &s).is_err());
    s.dim = 3;
    s.scene_text = "a\0b";
    assert!(write_snapshot(&path, &s).is_err());
    assert!(names_in(dir.path()).is_empty());
}

#[test]
fn failure_after_validation_leaves_no_final_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("snapshot_0000.h5");
    // A directory squatting on the temporary name makes the write fail.
    fs::create_dir(dir.path().join(".snapshot_0000.h5.tmp")).unwrap();
    let g = Phase::new(3, 1);
    let err = write_snapshot(&path, &snap(Some(g.view(0.1, true, false)), vec![])).unwrap_err();
    assert!(err.to_string().contains(".snapshot_0000.h5.tmp"), "{err}");
    assert!(!path.exists());
}

#[test]
fn large_multiline_scene_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.h5");
    // Well past the 64 KiB object-header limit that fixed-size attributes hit.
    let scene: String = (0..5000)
        .map(|i| format!("key_{i} = \"värde {i} ✓\"\n"))
        .collect();
    assert!(scene.len() > 100_000);
    let mut s = snap(None, vec![]);
    s.scene_text = &scene;
    write_snapshot(&path, &s).unwrap();
    assert_eq!(read_snapshot(&path).unwrap().scene_text, scene);
}

#[test]
fn reading_a_missing_or_foreign_file_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let missing: PathBuf = dir.path().join("nope.h5");
    let err = read_snapshot(&missing).unwrap_err();
    assert!(
        err.to_string().contains(&*missing.to_string_lossy()),
        "{err}"
    );

    let junk = dir.path().join("junk.h5");
    fs::write(&junk, b"not hdf5").unwrap();
    let err = read_snapshot(&junk).unwrap_err();
    assert!(err.to_string().contains(&*junk.to_string_lossy()), "{err}");
    assert_eq!(err.path(), junk.as_path());
}

#[test]
fn reader_rejects_counts_that_disagree_with_the_data() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.h5");
    let g = Phase::new(3, 1);
    write_snapshot(&path, &snap(Some(g.view(0.1, true, false)), vec![])).unwrap();
    {
        let f = File::open_rw(&path).unwrap();
        let h = f.group("Header").unwrap();
        for n in ["NumPart_ThisFile", "NumPart_Total"] {
            h.attr(n)
                .unwrap()
                .write_raw(&[4u64, 0, 0, 0, 0, 0][..])
                .unwrap();
        }
    }
    let err = read_snapshot(&path).unwrap_err();
    assert!(err.to_string().contains("/PartType0/"), "{err}");
}

/// Each process's share of a phase: rows `lo..hi` of it.
fn rows<'a>(v: &PhaseView<'a>, lo: usize, hi: usize) -> PhaseView<'a> {
    PhaseView {
        x: &v.x[lo..hi],
        v: &v.v[lo..hi],
        m: &v.m[lo..hi],
        rho: &v.rho[lo..hi],
        h: v.h,
        h_each: v.h_each.map(|h| &h[lo..hi]),
        id: &v.id[lo..hi],
        e: v.e.map(|e| &e[lo..hi]),
        p: v.p.map(|p| &p[lo..hi]),
        t_stop: v.t_stop.map(|t| &t[lo..hi]),
    }
}

/// A snapshot written by share over three processes (uneven shares, an empty one, chunks of
/// 32768 rows that straddle the shares, a process whose only rows of a fraction lie inside
/// another's chunk) reads back as the one process's file of the shares laid end to end, bit
/// for bit, on every dataset; the box is the whole's.
#[test]
fn a_snapshot_written_by_share_reads_back_as_the_whole_written_alone() {
    let dir = tempfile::tempdir().unwrap();
    let (gas, d0, d1) = (
        Phase::new(70_001, 1),
        Phase::new(40_000, 2),
        Phase::new(30_001, 3),
    );
    let h = 0.03;
    let whole = snap(
        Some(gas.view(h, true, false)),
        vec![d0.view(h, false, true), d1.view(h, false, true)],
    );
    let alone = dir.path().join("alone.h5");
    write_snapshot(&alone, &whole).unwrap();
    // Rows of the gas, of fraction 0, of fraction 1 per process.
    let cuts = [
        [0, 30_000, 30_000, 70_001],
        [0, 10, 40_000, 40_000],
        [0, 15_000, 30_000, 30_001],
    ];
    let shared = dir.path().join("shared.h5");
    let got: Vec<Result<[u64; 2], String>> = std::thread::scope(|s| {
        let handles: Vec<_> = (crate::dist::threads::Threads::group(3)
            .into_iter()
            .enumerate())
        .map(|(q, c)| {
            let (whole, shared) = (&whole, &shared);
            s.spawn(move || {
                let g = whole.gas.as_ref().unwrap();
                let mine = snap(
                    Some(rows(g, cuts[0][q], cuts[0][q + 1])),
                    vec![
                        rows(&whole.dust[0], cuts[1][q], cuts[1][q + 1]),
                        rows(&whole.dust[1], cuts[2][q], cuts[2][q + 1]),
                    ],
                );
                write_snapshot_shared(shared, &mine, &c, &crate::io::chunks::OnCores)
                    .map_err(|e| e.to_string())
            })
        })
        .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for r in &got {
        assert_eq!(r.as_ref().unwrap(), &[70_001, 70_001]);
    }
    assert_eq!(
        read_snapshot(&shared).unwrap(),
        read_snapshot(&alone).unwrap()
    );
    let file = File::open(&shared).unwrap();
    assert_eq!(
        file.dataset("PartType3/Coordinates").unwrap().filters(),
        vec![Filter::Shuffle, Filter::Deflate(4)]
    );
}

/// A process whose share lacks a column the others have stops the write on every process,
/// with one message, and no file is left.
#[test]
fn a_write_by_share_refused_on_one_process_leaves_no_file_on_any() {
    let dir = tempfile::tempdir().unwrap();
    let d0 = Phase::new(100, 2);
    let path = dir.path().join("s.h5");
    let got: Vec<String> = std::thread::scope(|s| {
        let handles: Vec<_> = (crate::dist::threads::Threads::group(2)
            .into_iter()
            .enumerate())
        .map(|(q, c)| {
            let (d0, path) = (&d0, &path);
            s.spawn(move || {
                let mine = snap(
                    None,
                    vec![rows(&d0.view(0.1, false, q == 0), 50 * q, 50 * q + 50)],
                );
                write_snapshot_shared(path, &mine, &c, &crate::io::chunks::OnCores)
                    .unwrap_err()
                    .to_string()
            })
        })
        .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert_eq!(got[0], got[1]);
    assert!(got[0].contains("different columns"), "{}", got[0]);
    assert!(
        names_in(dir.path()).is_empty(),
        "{:?}",
        names_in(dir.path())
    );
}
