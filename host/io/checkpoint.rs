//! Checkpoints: the whole particle state in memory order (over MPI ranks each phase rank by
//! rank, each written by its rank, and read back a block of rows a rank), bit for bit, plus
//! the scene and the driver's progress, so that `dustsph resume` continues exactly as if never
//! stopped.
use super::chunks::RowShare;
use super::h5::{get_rows, get_scalar, get_string, get_vec3_rows, h5err, put_scalar};
use super::shared::{create_shared, go_on, same_columns, SharedGroup};
use super::{commit_tmp, IoError, WithPath};
use crate::particles::{ClosingForces, Gas, Phase, State};
use hdf5::types::VarLenUnicode;
use hdf5::{File, Group};
use std::ops::Range;
use std::path::Path;

/// File name of the checkpoint inside an output directory.
pub const CHECKPOINT_NAME: &str = "checkpoint.h5";

/// What a checkpoint holds besides the particles.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointMeta {
    pub scene_text: String,
    pub scene_file: String,
    /// The `--set` overrides of the original run, as JSON (a list of strings).
    pub overrides_json: String,
    /// The driver's progress (output schedule, accumulated diagnostics), as JSON.
    pub progress_json: String,
}

fn vlu(path: &Path, s: &str) -> Result<VarLenUnicode, IoError> {
    s.parse::<VarLenUnicode>()
        .map_err(|e| IoError::invalid(path, format!("text not storable: {e}")))
}

/// A phase's group, this process's rows of it (`share` of its rows' count) and that count.
fn get_phase(
    file: &File,
    name: &str,
    share: &dyn Fn(usize) -> Range<usize>,
    path: &Path,
) -> Result<(Group, Phase, usize), IoError> {
    let g = file.group(name).map_err(h5err(path, name))?;
    let ds = g.dataset("m").map_err(h5err(path, name))?;
    let n = ds.shape().first().copied().unwrap_or(0);
    let rows = share(n);
    let vec3 = |c: &str| get_vec3_rows(&g, c, n, rows.clone(), path);
    let fixed: Option<Vec<u8>> = match g.link_exists("fixed") {
        true => Some(get_rows(&g, "fixed", &[n], rows.clone(), path)?),
        false => None,
    };
    let ph = Phase {
        x: vec3("x")?,
        v: vec3("v")?,
        m: get_rows(&g, "m", &[n], rows.clone(), path)?,
        rho: get_rows(&g, "rho", &[n], rows.clone(), path)?,
        id: get_rows(&g, "id", &[n], rows.clone(), path)?,
        fixed: fixed.map(|f| f.into_iter().map(|b| b != 0).collect()),
    };
    Ok((g, ph, n))
}

/// FNV-1a, fed the checkpoint's numbers and texts in their order.
struct Fnv(u64);

impl Fnv {
    fn new() -> Fnv {
        Fnv(0xcbf2_9ce4_8422_2325)
    }

    fn eat(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

/// What a checkpoint holds besides its phases' base columns, in the digest's order: the gas's
/// columns (name, values a row), each where present.
const GAS_COLUMNS: [(&str, usize); 6] = [
    ("p", 1),
    ("c", 1),
    ("e", 1),
    ("h", 1),
    ("omega", 1),
    ("next_forces", 5),
];

/// FNV-1a over every number and text of a checkpoint in a fixed order: a checkpoint whose
/// arrays were cut short or altered no longer matches the digest stored in it. Each column of
/// floats is its length then its values; the IDs and the fixed flags their values alone.
pub fn digest(state: &State, meta: &CheckpointMeta) -> u64 {
    let mut h = Fnv::new();
    let f = |v: &[f64], h: &mut Fnv| {
        h.eat(&(v.len() as u64).to_le_bytes());
        for x in v {
            h.eat(&x.to_bits().to_le_bytes());
        }
    };
    let phase = |ph: &Phase, h: &mut Fnv| {
        f(ph.x.as_flattened(), h);
        f(ph.v.as_flattened(), h);
        f(&ph.m, h);
        f(&ph.rho, h);
        for i in &ph.id {
            h.eat(&i.to_le_bytes());
        }
        if let Some(fx) = &ph.fixed {
            h.eat(&fx.iter().map(|&b| b as u8).collect::<Vec<u8>>());
        }
    };
    h.eat(&state.t.to_bits().to_le_bytes());
    h.eat(&state.step.to_le_bytes());
    phase(&state.gas.ph, &mut h);
    for (_, v) in gas_columns(&state.gas) {
        f(&v, &mut h);
    }
    for d in &state.dust {
        phase(d, &mut h);
    }
    eat_meta(meta, &mut h);
    h.0
}

/// The gas's columns of [`GAS_COLUMNS`] that it has, flattened.
fn gas_columns(g: &Gas) -> Vec<(&'static str, std::borrow::Cow<'_, [f64]>)> {
    use std::borrow::Cow::Borrowed;
    let flat = (g.closing_forces.as_deref()).map(bytemuck::cast_slice::<ClosingForces, f64>);
    [
        Some(&g.p[..]),
        Some(&g.c[..]),
        g.e.as_deref(),
        g.h.as_deref(),
        g.omega.as_deref(),
        flat,
    ]
    .into_iter()
    .zip(GAS_COLUMNS)
    .filter_map(|(v, (name, _))| v.map(|v| (name, Borrowed(v))))
    .collect()
}

fn eat_meta(meta: &CheckpointMeta, h: &mut Fnv) {
    for t in [
        &meta.scene_text,
        &meta.scene_file,
        &meta.overrides_json,
        &meta.progress_json,
    ] {
        h.eat(t.as_bytes());
        h.eat(&[0]);
    }
}

/// [`digest`] of a checkpoint's file as written (its `t` and `step` given), each column read
/// back a block of rows at a time: no process holds the whole state to make it.
fn digest_of_file(
    file: &File,
    (t, step, n_dust): (f64, u64, usize),
    meta: &CheckpointMeta,
    path: &Path,
) -> Result<u64, IoError> {
    const BLOCK: usize = 1 << 16;
    let mut h = Fnv::new();
    h.eat(&t.to_bits().to_le_bytes());
    h.eat(&step.to_le_bytes());
    // A column's bytes as stored, block by block (little-endian, as the digest eats them).
    let column = |g: &Group, name: &str, prefix: bool, h: &mut Fnv| -> Result<(), IoError> {
        let obj = format!("{}/{name}", g.name());
        let ds = g.dataset(name).map_err(h5err(path, &obj))?;
        let shape = ds.shape();
        let rows = shape.first().copied().unwrap_or(0);
        let width: usize = shape.iter().skip(1).product();
        if prefix {
            h.eat(&((rows * width) as u64).to_le_bytes());
        }
        let elem = ds.dtype().map_err(h5err(path, &obj))?.size();
        for lo in (0..rows).step_by(BLOCK) {
            let hi = (lo + BLOCK).min(rows);
            let e = h5err(path, &obj);
            match (elem, width) {
                (8, 1) if name == "id" => {
                    let v = ds.read_slice_1d::<u64, _>(lo..hi).map_err(e)?;
                    h.eat(bytemuck::cast_slice(&v.to_vec()));
                }
                (8, 1) => {
                    let v = ds.read_slice_1d::<f64, _>(lo..hi).map_err(e)?;
                    h.eat(bytemuck::cast_slice(&v.to_vec()));
                }
                (8, _) => {
                    let v = ds.read_slice_2d::<f64, _>((lo..hi, ..)).map_err(e)?;
                    h.eat(bytemuck::cast_slice(&v.into_raw_vec_and_offset().0));
                }
                _ => h.eat(&ds.read_slice_1d::<u8, _>(lo..hi).map_err(e)?.to_vec()),
            }
        }
        Ok(())
    };
    let phase = |g: &Group, h: &mut Fnv| -> Result<(), IoError> {
        for name in ["x", "v", "m", "rho"] {
            column(g, name, true, h)?;
        }
        column(g, "id", false, h)?;
        if g.link_exists("fixed") {
            column(g, "fixed", false, h)?;
        }
        Ok(())
    };
    let gas = file.group("gas").map_err(h5err(path, "/gas"))?;
    phase(&gas, &mut h)?;
    for (name, _) in GAS_COLUMNS {
        if gas.link_exists(name) {
            column(&gas, name, true, &mut h)?;
        }
    }
    for k in 0..n_dust {
        let name = format!("dust{k}");
        let g = file.group(&name).map_err(h5err(path, &name))?;
        phase(&g, &mut h)?;
    }
    eat_meta(meta, &mut h);
    Ok(h.0)
}

/// Write `state` and `meta` to `path` atomically (temporary name, then rename).
pub fn write_checkpoint(path: &Path, state: &State, meta: &CheckpointMeta) -> Result<(), IoError> {
    write_checkpoint_shared(path, state, meta, &crate::dist::Alone)
}

/// [`write_checkpoint`] of the particles every process of `c` holds a share of (`state`: this
/// process's; collective): one file, each phase's rows process by process, process 0 writing
/// it (each chunk filtered where its first row lies: [`super::chunks::write_rows_shared`]) and
/// its digest, read back a block at a time over several processes. Every process returns the
/// first process's error; no file is left then.
pub fn write_checkpoint_shared(
    path: &Path,
    state: &State,
    meta: &CheckpointMeta,
    c: &dyn crate::dist::Comm,
) -> Result<(), IoError> {
    let me = c.rank() as usize;
    // Which columns each phase has, and this process's rows of each.
    let phases: Vec<&Phase> = std::iter::once(&state.gas.ph).chain(&state.dust).collect();
    let gas_cols = gas_columns(&state.gas);
    let mut mine: Vec<u64> = vec![state.dust.len() as u64];
    mine.extend(phases.iter().map(|p| p.fixed.is_some() as u64));
    mine.extend(GAS_COLUMNS.map(|(n, _)| gas_cols.iter().any(|g| g.0 == n) as u64));
    let flags = mine.len();
    mine.extend(phases.iter().map(|p| p.len() as u64));
    let all = same_columns(c, path, &mine, flags)?;
    let shares: Vec<RowShare> = (0..phases.len())
        .map(|k| {
            RowShare::of(
                &all.iter().map(|v| vec![v[flags + k]]).collect::<Vec<_>>(),
                me,
            )
        })
        .collect();
    let begin = |file: &File| {
        let root = file.as_group().map_err(h5err(path, "/"))?;
        put_scalar(&root, "t", &state.t, path)?;
        put_scalar(&root, "step", &state.step, path)?;
        put_scalar(&root, "n_dust", &(state.dust.len() as u64), path)?;
        put_scalar(&root, "scene_text", &vlu(path, &meta.scene_text)?, path)?;
        put_scalar(&root, "scene_file", &vlu(path, &meta.scene_file)?, path)?;
        put_scalar(&root, "overrides", &vlu(path, &meta.overrides_json)?, path)?;
        put_scalar(&root, "progress", &vlu(path, &meta.progress_json)?, path)
    };
    let (tmp, file) = create_shared(c, path, begin)?;
    let result = (|| {
        for (k, ph) in phases.iter().enumerate() {
            let name = if k == 0 {
                "gas".to_string()
            } else {
                format!("dust{}", k - 1)
            };
            let g = file
                .as_ref()
                .map(|f| f.create_group(&name).map_err(h5err(path, &name)));
            let filter = &super::chunks::OnCores;
            let at = SharedGroup {
                g: g.as_ref(),
                share: &shares[k],
                path,
                c,
                filter,
            };
            at.put("x", ph.x.as_flattened(), 3)?;
            at.put("v", ph.v.as_flattened(), 3)?;
            at.put("m", &ph.m, 1)?;
            at.put("rho", &ph.rho, 1)?;
            at.put("id", &ph.id, 1)?;
            if let Some(f) = &ph.fixed {
                at.put("fixed", &f.iter().map(|&b| b as u8).collect::<Vec<u8>>(), 1)?;
            }
            if k == 0 {
                for (name, v) in &gas_cols {
                    let width = GAS_COLUMNS.iter().find(|g| g.0 == *name).map_or(1, |g| g.1);
                    at.put(name, v, width)?;
                }
            }
        }
        // The digest: from memory on one process, else read back from the file.
        let closed = match file {
            Some(file) => {
                let sum = match c.size() {
                    1 => Ok(digest(state, meta)),
                    _ => digest_of_file(&file, (state.t, state.step, state.dust.len()), meta, path),
                };
                sum.and_then(|sum| {
                    let root = file.as_group().map_err(h5err(path, "/"))?;
                    put_scalar(&root, "checksum", &sum, path)
                })
                .and_then(|()| file.close().map_err(h5err(path, "")))
                .and_then(|()| commit_tmp(&tmp, path))
            }
            None => Ok(()),
        };
        go_on(c, path, closed)
    })();
    if result.is_err() && me == 0 {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Read a checkpoint written by [`write_checkpoint`] or [`write_checkpoint_shared`].
pub fn read_checkpoint(path: &Path) -> Result<(State, CheckpointMeta), IoError> {
    read_checkpoint_on(path, &crate::dist::Alone).map(|r| (r.state, r.meta))
}

/// A checkpoint as one of several processes reads it.
pub struct CheckpointShare {
    /// This process's share of the particles: of each phase a contiguous block of its rows
    /// ([`crate::dist::share_rows`]); every particle on one process.
    pub state: State,
    pub meta: CheckpointMeta,
    /// Every process's particles together: the gas's, then each dust fraction's.
    pub counts: Vec<usize>,
}

/// [`read_checkpoint`] as one of the processes of `c` (collective): each reads its share of
/// each phase's rows (written by any number of processes, or by one), and process 0 checks the
/// digest, reading the file back a block of rows at a time, so no process holds every
/// particle; one process checks it from memory. Every process returns the first error of
/// any.
pub fn read_checkpoint_on(
    path: &Path,
    c: &dyn crate::dist::Comm,
) -> Result<CheckpointShare, IoError> {
    let (rank, size) = (c.rank(), c.size());
    let block = super::ics::row_block();
    let share = move |n: usize| {
        let (lo, hi) = crate::dist::share_rows(n, block, rank, size);
        lo..hi
    };
    let read = (|| {
        std::fs::metadata(path).with_path(path)?;
        let file = File::open(path).map_err(h5err(path, ""))?;
        let root = file.as_group().map_err(h5err(path, "/"))?;
        let n_dust: u64 = get_scalar(&root, "n_dust", path)?;
        let (g, gas_ph, n) = get_phase(&file, "gas", &share, path)?;
        let rows = share(n);
        let optional = |name: &str| -> Result<Option<Vec<f64>>, IoError> {
            match g.link_exists(name) {
                true => get_rows(&g, name, &[n], rows.clone(), path).map(Some),
                false => Ok(None),
            }
        };
        let gas = Gas {
            p: get_rows(&g, "p", &[n], rows.clone(), path)?,
            c: get_rows(&g, "c", &[n], rows.clone(), path)?,
            e: optional("e")?,
            h: optional("h")?,
            omega: optional("omega")?,
            // The closing forces' column keeps its first name (files written before read).
            closing_forces: if g.link_exists("next_forces") {
                let flat: Vec<f64> = get_rows(&g, "next_forces", &[n, 5], rows.clone(), path)?;
                Some(
                    flat.chunks_exact(5)
                        .map(|c| ClosingForces {
                            acc: [c[0], c[1], c[2]],
                            dedt: c[3],
                            vsig: c[4],
                        })
                        .collect(),
                )
            } else {
                None
            },
            ph: gas_ph,
        };
        let mut counts = vec![n];
        let mut dust = Vec::new();
        for k in 0..n_dust {
            let (_, ph, n) = get_phase(&file, &format!("dust{k}"), &share, path)?;
            counts.push(n);
            dust.push(ph);
        }
        let state = State {
            t: get_scalar(&root, "t", path)?,
            step: get_scalar(&root, "step", path)?,
            gas,
            dust,
        };
        let meta = CheckpointMeta {
            scene_text: get_string(&root, "scene_text", path)?,
            scene_file: get_string(&root, "scene_file", path)?,
            overrides_json: get_string(&root, "overrides", path)?,
            progress_json: get_string(&root, "progress", path)?,
        };
        // A checkpoint is whole only if its digest matches what it holds.
        let stored: u64 = get_scalar(&root, "checksum", path).map_err(|_| {
            IoError::invalid(
                path,
                "no checksum: not a whole dustsph checkpoint (or one written before checksums)",
            )
        })?;
        let now = match (size, rank) {
            (1, _) => Some(digest(&state, &meta)),
            (_, 0) => {
                let at = (state.t, state.step, n_dust as usize);
                Some(digest_of_file(&file, at, &meta, path)?)
            }
            _ => None,
        };
        if let Some(now) = now.filter(|&now| now != stored) {
            return Err(IoError::invalid(
                path,
                format!(
                    "checksum mismatch (stored {stored:016x}, contents {now:016x}): the \
                     checkpoint was altered or is incomplete"
                ),
            ));
        }
        Ok(CheckpointShare {
            state,
            meta,
            counts,
        })
    })();
    go_on(c, path, read)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_every_bit() {
        let ph = |n: usize, fixed: bool| Phase {
            x: (0..n)
                .map(|i| [i as f64 * 0.1, -0.0, f64::MIN_POSITIVE])
                .collect(),
            v: (0..n)
                .map(|i| [1.0 / (i as f64 + 3.0), 0.0, 1e300])
                .collect(),
            m: vec![0.1; n],
            rho: vec![1.0 / 3.0; n],
            id: (0..n as u64).collect(),
            fixed: fixed.then(|| (0..n).map(|i| i % 3 == 0).collect()),
        };
        let state = State {
            t: 0.123456789,
            step: 42,
            gas: Gas {
                ph: ph(7, true),
                p: vec![0.7; 7],
                c: vec![1.1; 7],
                e: Some(vec![2.5; 7]),
                h: Some(vec![0.01; 7]),
                omega: None,
                closing_forces: None,
            },
            dust: vec![ph(5, false), ph(0, false)],
        };
        let meta = CheckpointMeta {
            scene_text: "[scene]\nname = \"ü\"\n".into(),
            scene_file: "configs/x.toml".into(),
            overrides_json: "[\"a=1\"]".into(),
            progress_json: "{\"next\":3}".into(),
        };
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(CHECKPOINT_NAME);
        write_checkpoint(&p, &state, &meta).unwrap();
        let (s2, m2) = read_checkpoint(&p).unwrap();
        assert_eq!(s2, state);
        assert_eq!(m2, meta);
        assert!(
            std::fs::read_dir(dir.path()).unwrap().count() == 1,
            "no temporary left behind"
        );
    }

    /// A checkpoint written over 3 processes (threads; an empty share, a fraction held by
    /// one process alone) reads back whole, its digest read back from the file equal to the
    /// one made from the state in memory, each phase's rows the shares' end to end.
    #[test]
    fn a_checkpoint_written_by_share_reads_back_whole_and_by_share_with_its_digest() {
        let ph = |n: usize, seed: u64| Phase {
            x: (0..n)
                .map(|i| [i as f64 * 0.1 + seed as f64, -0.0, 1e-300])
                .collect(),
            v: (0..n)
                .map(|i| [1.0 / (i as f64 + 3.0), 0.0, 1e300])
                .collect(),
            m: vec![0.1; n],
            rho: (0..n).map(|i| 1.0 + i as f64 / 7.0).collect(),
            id: (0..n as u64).map(|i| seed << 32 | i).collect(),
            fixed: None,
        };
        let cut = |p: &Phase, lo: usize, hi: usize| {
            let mut q = p.clone();
            q.retain_rows(&(0..p.len()).map(|i| i >= lo && i < hi).collect::<Vec<_>>());
            q
        };
        let n = 100_000;
        let whole = State {
            t: 0.5,
            step: 7,
            gas: Gas {
                ph: ph(n, 0),
                p: (0..n).map(|i| i as f64).collect(),
                c: vec![1.1; n],
                e: None,
                h: Some(vec![0.01; n]),
                omega: Some(vec![1.0; n]),
                closing_forces: Some(
                    (0..n)
                        .map(|i| ClosingForces {
                            acc: [i as f64, 1.0, 2.0],
                            dedt: 3.0,
                            vsig: 4.0,
                        })
                        .collect(),
                ),
            },
            dust: vec![ph(70_000, 1), ph(3, 2)],
        };
        let meta = CheckpointMeta {
            scene_text: "[scene]".into(),
            scene_file: "x.toml".into(),
            overrides_json: "[]".into(),
            progress_json: "{}".into(),
        };
        let cuts = [[0, 40_000, 40_000, n], [0, 1, 50_000, 70_000], [0, 0, 3, 3]];
        let share = |q: usize| {
            let mut g = whole.gas.clone();
            let keep: Vec<bool> = (0..n)
                .map(|i| i >= cuts[0][q] && i < cuts[0][q + 1])
                .collect();
            g.retain_rows(&keep);
            State {
                t: whole.t,
                step: whole.step,
                gas: g,
                dust: (1..3)
                    .map(|k| cut(&whole.dust[k - 1], cuts[k][q], cuts[k][q + 1]))
                    .collect(),
            }
        };
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(CHECKPOINT_NAME);
        std::thread::scope(|s| {
            let handles: Vec<_> = (crate::dist::threads::Threads::group(3)
                .into_iter()
                .enumerate())
            .map(|(q, c)| {
                let (mine, p, meta) = (share(q), &p, &meta);
                s.spawn(move || write_checkpoint_shared(p, &mine, meta, &c).unwrap())
            })
            .collect();
            handles.into_iter().for_each(|h| h.join().unwrap());
        });
        let (back, m2) = read_checkpoint(&p).unwrap();
        assert_eq!(back, whole);
        assert_eq!(m2, meta);
        let file = File::open(&p).unwrap();
        let sum = digest_of_file(&file, (0.5, 7, 2), &meta, &p).unwrap();
        assert_eq!(sum, digest(&whole, &meta));
        drop(file);
        // Read back by share over 3 processes: each its block of each phase's rows, together
        // the whole, and the counts of the whole on each.
        let read = std::thread::scope(|s| {
            let handles: Vec<_> = (crate::dist::threads::Threads::group(3).into_iter())
                .map(|c| {
                    let p = &p;
                    s.spawn(move || read_checkpoint_on(p, &c).unwrap())
                })
                .collect();
            let shares: Vec<CheckpointShare> =
                handles.into_iter().map(|h| h.join().unwrap()).collect();
            shares
        });
        let block = super::super::ics::row_block();
        let join = |a: &mut Phase, b: &Phase| {
            a.x.extend(&b.x);
            a.v.extend(&b.v);
            a.m.extend(&b.m);
            a.rho.extend(&b.rho);
            a.id.extend(&b.id);
        };
        let mut joined = read[0].state.clone();
        for (q, r) in read.iter().enumerate() {
            assert_eq!(r.counts, vec![n, 70_000, 3]);
            assert_eq!(r.meta, meta);
            let (lo, hi) = crate::dist::share_rows(n, block, q as u32, 3);
            assert_eq!(r.state.gas.ph.len(), hi - lo, "process {q}");
            if q > 0 {
                join(&mut joined.gas.ph, &r.state.gas.ph);
                for (k, d) in r.state.dust.iter().enumerate() {
                    join(&mut joined.dust[k], d);
                }
            }
        }
        assert_eq!(joined.gas.ph, whole.gas.ph);
        assert_eq!(joined.dust, whole.dust);
        assert_eq!(
            read[2].state.gas.p,
            whole.gas.p[whole.gas.p.len() - read[2].state.gas.p.len()..]
        );
    }
}
