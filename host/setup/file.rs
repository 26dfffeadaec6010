//! Initial conditions from a user's HDF5 file (`scene.problem = "file"`, `[file]`): the file is
//! read and checked by host/io/ics.rs; here it meets the scene (its dimension, periodic axes,
//! fractions, equation of state and smoothing-length rule), each failure naming the file,
//! the dataset and the first offending row.
use super::*;
use crate::dist::{agree_first, Comm};
use crate::io::ics::{read_ics_on, row_block, IcPhase, Ics};
use crate::scene::{FileCfg, GasEos, SmoothingLength};

/// Where a run's particles came from: the file and the SHA-256 of its bytes (every output
/// records both).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IcSource {
    pub path: String,
    pub sha256: String,
}

/// The file's particles as this process's share of a set-up over `c` (each process reads its
/// own rows of the file, [`read_ics_on`]; one process reads them all): the sums and checks
/// over every row are collective, and every process stops with the same error.
pub(super) fn build(scene: &Scene, f: &FileCfg, c: &dyn Comm) -> Result<Setup, SetupError> {
    let path = &f.resolved;
    let fail = |msg: String| SetupError {
        key: "file.path".into(),
        msg,
    };
    let io = |e: crate::io::IoError| fail(e.to_string());
    // The digest goes into the outputs, which rank 0 writes.
    let sha256 = if c.rank() == 0 {
        crate::io::sha256::file_digest(path).map_err(io)
    } else {
        Ok(String::new())
    };
    let sha256 = agreed(c, sha256)?;
    let ics = read_ics_on(path, c).map_err(io)?;
    let at = |msg: String| fail(format!("{}: {msg}", path.display()));
    // Each check's place in the order one process takes them: the error named is the first
    // check's that fails anywhere, at its lowest row.
    let step = std::cell::Cell::new(0u64);
    let checked = check_rows(scene, f, &ics, &at, &step).map_err(|e| (step.get(), e));
    let (periodic, e) = agreed_first(c, checked)?;
    let dim = scene.dim();
    let nf = scene.n_fractions();
    let volume = periodic_volume(&periodic, dim);
    let spacing = mean_spacing(&ics.gas, dim, volume, c);
    let h = agreed(c, smoothing(scene, &ics.gas, spacing, &at, c))?;
    for (k, p) in periodic.iter().enumerate() {
        if let Some((_, len)) = p {
            check_periodic_fits(*len, h, &format!("file.periodic.{k}"))?;
        }
    }
    // Densities not in the file: m / spacing^d, a start only (summation replaces them before
    // the first step; continuity needs the file's).
    let guess = |ph: &IcPhase| -> Vec<f64> {
        ph.rho
            .clone()
            .unwrap_or_else(|| ph.m.iter().map(|m| m / spacing.powi(dim as i32)).collect())
    };
    let ng = ics.gas.total;
    // Ids the file does not give follow the largest it does (unique over every phase), by
    // the row in the file.
    let next = |ph: Option<&IcPhase>| {
        let mine = ph
            .and_then(|p| p.id.as_ref())
            .and_then(|ids| ids.iter().max());
        largest(c, mine.copied()).map_or(0, |m| m + 1)
    };
    let gas_start = next(ics.dust.as_ref());
    let first = ics.gas.first as u64;
    let gas = Phase {
        x: ics.gas.x.clone(),
        v: ics.gas.v.clone(),
        m: ics.gas.m.clone(),
        rho: guess(&ics.gas),
        id: ics.gas.id.clone().unwrap_or_else(|| {
            let n = ics.gas.len() as u64;
            (gas_start + first..gas_start + first + n).collect()
        }),
        fixed: None,
    };
    let dust = match &ics.dust {
        Some(d) => {
            let start = largest(c, gas.id.iter().max().copied()).map_or(0, |m| m + 1);
            let split = fractions(d, nf, start, &guess(d), &at);
            let split = agreed(c, split)?;
            // Every fraction holds a particle on some process.
            let mut counts: Vec<u64> = split.iter().map(|p| p.len() as u64).collect();
            c.sum_u64(&mut counts);
            if let Some(k) = counts.iter().position(|&n| n == 0) {
                return Err(at(format!(
                    "/PartType3 has no particle of fraction {k} (FractionIndex); the scene lists {nf}"
                )));
            }
            split
        }
        None => Vec::new(),
    };
    // The note's counts and masses over every process (block by block, as the spacing).
    let mut masses = blocked_sums(c, &ics.gas.m, |_| 0, 1);
    if let Some(d) = &ics.dust {
        let class = |i: usize| d.fraction.as_ref().map_or(0, |f| f[i] as usize);
        masses.extend(blocked_sums(c, &d.m, class, nf));
    }
    let mut counts: Vec<u64> = dust.iter().map(|d| d.len() as u64).collect();
    c.sum_u64(&mut counts);
    let gas_mass = masses[0];
    // Where the reference h comes from: recomputed from this file, so a restart from a later
    // snapshot (another extent) takes another one, which the user should hear.
    let how = match scene.sph.smoothing {
        SmoothingLength::Absolute { .. } => "sph.h",
        SmoothingLength::Hfact { .. } => {
            "the reference h: sph.hfact × this file's mean gas spacing (its IDIC cells and \
             grid; each particle's own h is solved)"
        }
        SmoothingLength::FromFile {} => "the file's SmoothingLength",
    };
    let mut notes = vec![format!(
        "initial conditions: {} (SHA-256 {sha256}): {ng} gas particles{}, t = {}, h = {h:.6e} \
         ({how})",
        path.display(),
        (counts.iter().zip(&masses[1..]).enumerate())
            .map(|(k, (n, m))| format!(", fraction {k}: {n} particles, ε = {:.6}", m / gas_mass))
            .collect::<String>(),
        ics.time
    )];
    if matches!(scene.sph.smoothing, SmoothingLength::Absolute { .. }) && ics.gas.h.is_some() {
        notes.push("the file's SmoothingLength is not used: sph.h sets h".into());
    }
    let mut su = Setup::at_start(
        gas_phase(gas, e),
        dust,
        h,
        crate::grid::Domain { dim, periodic },
        spacing,
        periodic[0].map_or(f64::NAN, |(_, len)| len),
    );
    su.state.t = ics.time;
    su.notes = notes;
    su.source = Some(IcSource {
        path: path.display().to_string(),
        sha256,
    });
    su.share = c.size() > 1;
    Ok(su)
}

/// A set-up's result agreed over the processes: the lowest failing rank's error on all.
fn agreed<T>(c: &dyn Comm, r: Result<T, SetupError>) -> Result<T, SetupError> {
    agreed_first(c, r.map_err(|e| (0, e)))
}

/// [`agreed`]: the error of the first check (its place given with it) that fails anywhere.
fn agreed_first<T>(c: &dyn Comm, r: Result<T, (u64, SetupError)>) -> Result<T, SetupError> {
    let text = |e: &SetupError| format!("{}\n{}", e.key, e.msg);
    let from = |m: String| {
        let (key, msg) = m.split_once('\n').unwrap_or(("file.path", &m));
        SetupError {
            key: key.into(),
            msg: msg.into(),
        }
    };
    agree_first(c, r, text, from)
}

/// The largest of every process's value (`None` where no process has one).
fn largest(c: &dyn Comm, mine: Option<u64>) -> Option<u64> {
    let bytes = mine.map(u64::to_le_bytes);
    let all = c.all_gather_bytes(bytes.as_ref().map_or(&[][..], |b| &b[..]));
    (all.iter())
        .filter(|b| b.len() == 8)
        .map(|b| u64::from_le_bytes(b[..].try_into().expect("8 bytes")))
        .max()
}

/// Per class (`class(row)` < `classes`), the sum of `values` over every process's rows: each
/// block of [`row_block`] rows summed in row order, then the blocks in file order (the same
/// sums on any number of processes; collective).
fn blocked_sums(
    c: &dyn Comm,
    values: &[f64],
    class: impl Fn(usize) -> usize,
    classes: usize,
) -> Vec<f64> {
    let b = row_block();
    let mut mine = vec![0.0; values.len().div_ceil(b) * classes];
    for (i, v) in values.iter().enumerate() {
        mine[i / b * classes + class(i)] += v;
    }
    let all = c.all_gather_bytes(bytemuck::cast_slice(&mine));
    let mut out = vec![0.0; classes];
    let blocks = all.iter().flat_map(|bytes| bytes.chunks_exact(8 * classes));
    for block in blocks {
        for (o, v) in out.iter_mut().zip(block.chunks_exact(8)) {
            *o += f64::from_le_bytes(v.try_into().expect("8 bytes"));
        }
    }
    out
}

/// The checks of this process's rows against the scene (no collective): the periodic axes
/// and the energy column, or the first error.
#[allow(clippy::type_complexity)]
fn check_rows(
    scene: &Scene,
    f: &FileCfg,
    ics: &Ics,
    at: &impl Fn(String) -> SetupError,
    step: &std::cell::Cell<u64>,
) -> Result<([Option<(f64, f64)>; 3], Option<Vec<f64>>), SetupError> {
    let dim = scene.dim();
    if let Some(d) = ics.dim {
        if d != dim {
            return Err(at(format!(
                "Header/Dimension is {d} but the scene's scene.dim is {dim}"
            )));
        }
    }
    let nf = scene.n_fractions();
    check_axes(ics, dim, &at, step)?;
    let periodic = periodic_box(ics, f, &at, step)?;
    // The checks below read only the file's layout: the same on every process.
    step.set(step.get() + 1);
    let dust_rows = ics.dust.as_ref().map_or(0, |d| d.total);
    match (nf, dust_rows) {
        (0, n) if n > 0 => {
            return Err(at(format!(
                "/PartType3 holds {n} dust particles but the scene has no [dust] section \
                 (give each fraction's law there)"
            )))
        }
        (k, 0) if k > 0 => {
            return Err(at(format!(
                "the scene lists {k} dust fraction(s) but the file has no dust (/PartType3)"
            )))
        }
        _ => {}
    }
    if ics.gas.total == 0 {
        return Err(at("/PartType0 holds no gas particles".into()));
    }
    let e = match scene.gas.eos {
        GasEos::Adiabatic { .. } => Some(ics.gas.e.clone().ok_or_else(|| {
            at("/PartType0/InternalEnergy is missing; adiabatic gas (gas.eos) needs it".into())
        })?),
        GasEos::Isothermal { .. } | GasEos::LocallyIsothermal { .. } => None,
    };
    if scene.sph.density == crate::scene::DensityMethod::Continuity && ics.gas.rho.is_none() {
        return Err(at(
            "/PartType0/Density is missing; sph.density = \"continuity\" starts from it".into(),
        ));
    }
    Ok((periodic, e))
}

/// Positions and velocities along axes the scene does not have must be 0.
fn check_axes(
    ics: &Ics,
    dim: u32,
    at: &impl Fn(String) -> SetupError,
    step: &std::cell::Cell<u64>,
) -> Result<(), SetupError> {
    for (name, ph) in [
        ("PartType0", Some(&ics.gas)),
        ("PartType3", ics.dust.as_ref()),
    ] {
        let Some(ph) = ph else { continue };
        for (col, rows) in [("Coordinates", &ph.x), ("Velocities", &ph.v)] {
            for k in dim as usize..3 {
                step.set(step.get() + 1);
                if let Some(i) = rows.iter().position(|r| r[k] != 0.0) {
                    let off = if col == "Coordinates" {
                        " (with Header/CoordinateOffset added)"
                    } else {
                        ""
                    };
                    return Err(at(format!(
                        "/{name}/{col}[{}] has {} along axis {k}{off}; a {dim}D scene needs 0 there",
                        ph.first + i,
                        rows[i][k]
                    )));
                }
            }
        }
    }
    Ok(())
}

/// The periodic axes' (lower end, length) from the header, every particle inside.
fn periodic_box(
    ics: &Ics,
    f: &FileCfg,
    at: &impl Fn(String) -> SetupError,
    step: &std::cell::Cell<u64>,
) -> Result<[Option<(f64, f64)>; 3], SetupError> {
    let mut out = [None; 3];
    for k in 0..3 {
        if !f.periodic[k] {
            continue;
        }
        let Some(size) = ics.box_size else {
            return Err(at(format!(
                "file.periodic.{k} is true but the file's Header has no BoxSizePerAxis or BoxSize \
                 to give the period"
            )));
        };
        let (lo, len) = (ics.offset[k], size[k]);
        if !(len.is_finite() && len > 0.0) {
            return Err(at(format!(
                "Header box size along axis {k} is {len} (a period must be > 0)"
            )));
        }
        for (name, ph) in [
            ("PartType0", Some(&ics.gas)),
            ("PartType3", ics.dust.as_ref()),
        ] {
            let Some(ph) = ph else { continue };
            step.set(step.get() + 1);
            if let Some(i) = ph.x.iter().position(|x| !(lo..lo + len).contains(&x[k])) {
                return Err(at(format!(
                    "/{name}/Coordinates[{}] is at {} along axis {k}, outside the periodic box \
                     [{lo}, {}) (Header CoordinateOffset and BoxSizePerAxis)",
                    ph.first + i,
                    ph.x[i][k],
                    lo + len
                )));
            }
        }
        out[k] = Some((lo, len));
    }
    Ok(out)
}

/// The periodic box's volume, if every axis of the scene is periodic.
fn periodic_volume(periodic: &[Option<(f64, f64)>; 3], dim: u32) -> Option<f64> {
    periodic[..dim as usize]
        .iter()
        .map(|p| p.map(|(_, len)| len))
        .product()
}

/// The gas's mean particle spacing: mean (m/ρ)^(1/d) from the file's densities, else
/// (V/N)^(1/d) of a periodic box, else the extent of the particles over N^(1/d); over every
/// process's rows (collective). The mean is summed in blocks of [`row_block`] rows, each in
/// row order, then block by block: the same sum for any number of processes.
fn mean_spacing(gas: &IcPhase, dim: u32, volume: Option<f64>, c: &dyn Comm) -> f64 {
    let n = gas.total as f64;
    let d = dim as f64;
    if let Some(rho) = &gas.rho {
        let each: Vec<f64> = (gas.m.iter().zip(rho))
            .map(|(m, r)| (m / r).powf(1.0 / d))
            .collect();
        return blocked_sums(c, &each, |_| 0, 1)[0] / n;
    }
    let v = volume.unwrap_or_else(|| {
        // Each axis's largest coordinate and largest negated one, over every process.
        let mut ends = [f64::NEG_INFINITY; 6];
        for x in &gas.x {
            for k in 0..3 {
                ends[k] = ends[k].max(x[k]);
                ends[3 + k] = ends[3 + k].max(-x[k]);
            }
        }
        c.max_f64(&mut ends);
        (0..dim as usize)
            .map(|k| (ends[k] + ends[3 + k]).max(f64::MIN_POSITIVE))
            .product()
    });
    (v / n).powf(1.0 / d)
}

/// The run's (reference) h: `sph.h`; `sph.hfact` × the mean spacing; or, with neither, the
/// file's gas `SmoothingLength`, which a fixed-h run needs the same for every particle.
fn smoothing(
    scene: &Scene,
    gas: &IcPhase,
    spacing: f64,
    at: &impl Fn(String) -> SetupError,
    c: &dyn Comm,
) -> Result<f64, SetupError> {
    match scene.sph.smoothing {
        SmoothingLength::Absolute { h } => Ok(h),
        SmoothingLength::Hfact { hfact, .. } => Ok(hfact * spacing),
        SmoothingLength::FromFile {} => {
            let Some(h) = &gas.h else {
                return Err(at(
                    "/PartType0/SmoothingLength is missing: give sph.h, or sph.hfact (h from \
                     the particle spacing)"
                        .into(),
                ));
            };
            // Row 0's h: the first of the lowest process holding rows.
            let firsts =
                c.all_gather_bytes(&h.first().map_or(Vec::new(), |x| x.to_le_bytes().to_vec()));
            let h0 = (firsts.iter().find(|b| b.len() == 8))
                .map(|b| f64::from_le_bytes(b[..].try_into().expect("8 bytes")))
                .expect("the file holds gas (checked before)");
            if let Some(i) = h.iter().position(|&x| x != h0) {
                return Err(at(format!(
                    "/PartType0/SmoothingLength varies ({} at row 0, {} at row {}): a fixed-h run \
                     takes one h; give sph.h, or sph.hfact with sph.variable_h = true",
                    2.0 * h0,
                    2.0 * h[i],
                    gas.first + i
                )));
            }
            Ok(h0)
        }
    }
}

/// The dust rows split into fractions by `FractionIndex` (kept in the file's order), with ids
/// from `id_start` on where the file has none.
fn fractions(
    d: &IcPhase,
    nf: usize,
    id_start: u64,
    rho: &[f64],
    at: &impl Fn(String) -> SetupError,
) -> Result<Vec<Phase>, SetupError> {
    let index: Vec<usize> = match &d.fraction {
        Some(fr) => fr
            .iter()
            .enumerate()
            .map(|(i, &k)| {
                usize::try_from(k).ok().filter(|&k| k < nf).ok_or_else(|| {
                    at(format!(
                        "/PartType3/FractionIndex[{}] is {k}; the scene has {nf} fraction(s) \
                         (0 to {})",
                        d.first + i,
                        nf - 1
                    ))
                })
            })
            .collect::<Result<_, _>>()?,
        None if nf == 1 => vec![0; d.len()],
        None => {
            return Err(at(format!(
                "/PartType3/FractionIndex is missing; the scene has {nf} fractions"
            )))
        }
    };
    let mut out: Vec<Phase> = (0..nf).map(|_| Phase::default()).collect();
    for (i, &k) in index.iter().enumerate() {
        let p = &mut out[k];
        p.x.push(d.x[i]);
        p.v.push(d.v[i]);
        p.m.push(d.m[i]);
        p.rho.push(rho[i]);
        let row = (d.first + i) as u64;
        p.id.push(d.id.as_ref().map_or(id_start + row, |id| id[i]));
    }
    Ok(out)
}
