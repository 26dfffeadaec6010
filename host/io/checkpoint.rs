//! Checkpoints: the whole particle state in memory order, bit for bit, plus the scene and the
//! driver's progress, so that `dustsph resume` continues exactly as if never stopped.
use super::snapshot::{
    get_column, get_optional, get_scalar, get_shaped, get_string, get_vec3, h5err, put_dataset,
    put_scalar,
};
use super::{commit_tmp, remove_stale, require_parent_dir, tmp_path, IoError, WithPath};
use crate::particles::{Gas, Phase, State};
use hdf5::types::VarLenUnicode;
use hdf5::{File, Group};
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

fn put_phase(file: &File, name: &str, ph: &Phase, path: &Path) -> Result<Group, IoError> {
    let g = file.create_group(name).map_err(h5err(path, name))?;
    let flat = |v: &[[f64; 3]]| -> Vec<f64> { v.iter().flatten().copied().collect() };
    put_dataset(&g, "x", &flat(&ph.x), 3, path)?;
    put_dataset(&g, "v", &flat(&ph.v), 3, path)?;
    put_dataset(&g, "m", &ph.m, 1, path)?;
    put_dataset(&g, "rho", &ph.rho, 1, path)?;
    put_dataset(&g, "id", &ph.id, 1, path)?;
    if let Some(f) = &ph.fixed {
        let f: Vec<u8> = f.iter().map(|&b| b as u8).collect();
        put_dataset(&g, "fixed", &f, 1, path)?;
    }
    Ok(g)
}

fn get_phase(file: &File, name: &str, path: &Path) -> Result<(Group, Phase), IoError> {
    let g = file.group(name).map_err(h5err(path, name))?;
    let ds = g.dataset("m").map_err(h5err(path, name))?;
    let n = ds.shape().first().copied().unwrap_or(0);
    let fixed: Option<Vec<u8>> = get_optional(&g, "fixed", n, path)?;
    let ph = Phase {
        x: get_vec3(&g, "x", n, path)?,
        v: get_vec3(&g, "v", n, path)?,
        m: get_column(&g, "m", n, path)?,
        rho: get_column(&g, "rho", n, path)?,
        id: get_shaped(&g, "id", &[n], path)?,
        fixed: fixed.map(|f| f.into_iter().map(|b| b != 0).collect()),
    };
    Ok((g, ph))
}

/// FNV-1a over every number and text of a checkpoint in a fixed order: a checkpoint whose
/// arrays were cut short or altered no longer matches the digest stored in it.
pub fn digest(state: &State, meta: &CheckpointMeta) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    let f = |v: &[f64], eat: &mut dyn FnMut(&[u8])| {
        eat(&(v.len() as u64).to_le_bytes());
        for x in v {
            eat(&x.to_bits().to_le_bytes());
        }
    };
    let phase = |ph: &Phase, eat: &mut dyn FnMut(&[u8])| {
        let flat = |v: &[[f64; 3]]| -> Vec<f64> { v.iter().flatten().copied().collect() };
        f(&flat(&ph.x), eat);
        f(&flat(&ph.v), eat);
        f(&ph.m, eat);
        f(&ph.rho, eat);
        for i in &ph.id {
            eat(&i.to_le_bytes());
        }
        if let Some(fx) = &ph.fixed {
            eat(&fx.iter().map(|&b| b as u8).collect::<Vec<u8>>());
        }
    };
    eat(&state.t.to_bits().to_le_bytes());
    eat(&state.step.to_le_bytes());
    phase(&state.gas.ph, &mut eat);
    f(&state.gas.p, &mut eat);
    f(&state.gas.c, &mut eat);
    for v in [&state.gas.e, &state.gas.h, &state.gas.omega]
        .into_iter()
        .flatten()
    {
        f(v, &mut eat);
    }
    if let Some(nf) = &state.gas.next_forces {
        f(
            &nf.iter().flatten().copied().collect::<Vec<f64>>(),
            &mut eat,
        );
    }
    for d in &state.dust {
        phase(d, &mut eat);
    }
    for t in [
        &meta.scene_text,
        &meta.scene_file,
        &meta.overrides_json,
        &meta.progress_json,
    ] {
        eat(t.as_bytes());
        eat(&[0]);
    }
    h
}

/// Write `state` and `meta` to `path` atomically (temporary name, then rename).
pub fn write_checkpoint(path: &Path, state: &State, meta: &CheckpointMeta) -> Result<(), IoError> {
    require_parent_dir(path)?;
    let tmp = tmp_path(path)?;
    remove_stale(&tmp)?;
    let result = (|| {
        let file = File::create_excl(&tmp).with_path(&tmp)?;
        let root = file.as_group().map_err(h5err(path, "/"))?;
        put_scalar(&root, "t", &state.t, path)?;
        put_scalar(&root, "step", &state.step, path)?;
        put_scalar(&root, "n_dust", &(state.dust.len() as u64), path)?;
        put_scalar(&root, "scene_text", &vlu(path, &meta.scene_text)?, path)?;
        put_scalar(&root, "scene_file", &vlu(path, &meta.scene_file)?, path)?;
        put_scalar(&root, "overrides", &vlu(path, &meta.overrides_json)?, path)?;
        put_scalar(&root, "progress", &vlu(path, &meta.progress_json)?, path)?;
        put_scalar(&root, "checksum", &digest(state, meta), path)?;
        let g = put_phase(&file, "gas", &state.gas.ph, path)?;
        put_dataset(&g, "p", &state.gas.p, 1, path)?;
        put_dataset(&g, "c", &state.gas.c, 1, path)?;
        for (name, f) in [
            ("e", &state.gas.e),
            ("h", &state.gas.h),
            ("omega", &state.gas.omega),
        ] {
            if let Some(f) = f {
                put_dataset(&g, name, f, 1, path)?;
            }
        }
        if let Some(f) = &state.gas.next_forces {
            let flat: Vec<f64> = f.iter().flatten().copied().collect();
            put_dataset(&g, "next_forces", &flat, 5, path)?;
        }
        for (k, d) in state.dust.iter().enumerate() {
            put_phase(&file, &format!("dust{k}"), d, path)?;
        }
        file.close().map_err(h5err(path, ""))
    })()
    .and_then(|()| commit_tmp(&tmp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Read a checkpoint written by [`write_checkpoint`].
pub fn read_checkpoint(path: &Path) -> Result<(State, CheckpointMeta), IoError> {
    std::fs::metadata(path).with_path(path)?;
    let file = File::open(path).map_err(h5err(path, ""))?;
    let root = file.as_group().map_err(h5err(path, "/"))?;
    let n_dust: u64 = get_scalar(&root, "n_dust", path)?;
    let (g, gas_ph) = get_phase(&file, "gas", path)?;
    let n = gas_ph.len();
    let gas = Gas {
        p: get_column(&g, "p", n, path)?,
        c: get_column(&g, "c", n, path)?,
        e: get_optional(&g, "e", n, path)?,
        h: get_optional(&g, "h", n, path)?,
        omega: get_optional(&g, "omega", n, path)?,
        next_forces: if g.link_exists("next_forces") {
            let flat: Vec<f64> = get_shaped(&g, "next_forces", &[n, 5], path)?;
            Some(
                flat.chunks_exact(5)
                    .map(|c| [c[0], c[1], c[2], c[3], c[4]])
                    .collect(),
            )
        } else {
            None
        },
        ph: gas_ph,
    };
    let dust = (0..n_dust)
        .map(|k| get_phase(&file, &format!("dust{k}"), path).map(|(_, p)| p))
        .collect::<Result<Vec<_>, _>>()?;
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
    let now = digest(&state, &meta);
    if stored != now {
        return Err(IoError::invalid(
            path,
            format!(
                "checksum mismatch (stored {stored:016x}, contents {now:016x}): the checkpoint \
                 was altered or is incomplete"
            ),
        ));
    }
    Ok((state, meta))
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
                next_forces: None,
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
}
