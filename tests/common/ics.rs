//! Initial-conditions files written as h5py would (float64, int64 ids), for the tests that
//! start from a file (`scene.problem = "file"`).
use dustsph::particles::{Phase, State};
use dustsph::scene::LoadedScene;
use std::path::Path;

/// One dataset as h5py would write it: float64 or int64, (N,) or (N, 3).
pub enum Column {
    F(Vec<f64>, usize),
    I(Vec<i64>),
}

/// An initial-conditions file to write: its Header's float attributes and its groups.
#[derive(Default)]
pub struct IcFile {
    pub header: Vec<(&'static str, Vec<f64>)>,
    pub groups: Vec<(&'static str, Vec<(&'static str, Column)>)>,
}

impl IcFile {
    /// A set-up's state as a file (h5py's layout: float64, int64 ids and indices, the
    /// support radius 2h as SmoothingLength, SWIFT's three-valued BoxSize).
    pub fn of_state(state: &State, h: f64, dim: u32, box_size: Option<[f64; 3]>) -> IcFile {
        let flat = |x: &[[f64; 3]]| x.iter().flatten().copied().collect::<Vec<_>>();
        let phase = |p: &Phase, fraction: Option<Vec<i64>>| {
            let mut cols = vec![
                ("Coordinates", Column::F(flat(&p.x), 3)),
                ("Velocities", Column::F(flat(&p.v), 3)),
                ("Masses", Column::F(p.m.clone(), 1)),
                ("Density", Column::F(p.rho.clone(), 1)),
                ("SmoothingLength", Column::F(vec![2.0 * h; p.len()], 1)),
                (
                    "ParticleIDs",
                    Column::I(p.id.iter().map(|&i| i as i64).collect()),
                ),
            ];
            if let Some(f) = fraction {
                cols.push(("FractionIndex", Column::I(f)));
            }
            cols
        };
        let mut gas = phase(&state.gas.ph, None);
        if let Some(e) = &state.gas.e {
            gas.push(("InternalEnergy", Column::F(e.clone(), 1)));
        }
        let mut groups = vec![("PartType0", gas)];
        if !state.dust.is_empty() {
            let all = Phase {
                x: state.dust.iter().flat_map(|d| d.x.clone()).collect(),
                v: state.dust.iter().flat_map(|d| d.v.clone()).collect(),
                m: state.dust.iter().flat_map(|d| d.m.clone()).collect(),
                rho: state.dust.iter().flat_map(|d| d.rho.clone()).collect(),
                id: state.dust.iter().flat_map(|d| d.id.clone()).collect(),
                fixed: None,
            };
            let fr = (state.dust.iter().enumerate())
                .flat_map(|(k, d)| vec![k as i64; d.len()])
                .collect();
            groups.push(("PartType3", phase(&all, Some(fr))));
        }
        let mut header = vec![("Time", vec![state.t]), ("Dimension", vec![dim as f64])];
        if let Some(b) = box_size {
            header.push(("BoxSize", b.to_vec()));
        }
        IcFile { header, groups }
    }

    pub fn column(&mut self, group: &str, name: &str) -> &mut Column {
        let g = self.groups.iter_mut().find(|g| g.0 == group).unwrap();
        &mut g.1.iter_mut().find(|c| c.0 == name).unwrap().1
    }

    pub fn remove(&mut self, group: &str, name: &str) {
        let g = self.groups.iter_mut().find(|g| g.0 == group).unwrap();
        g.1.retain(|c| c.0 != name);
    }

    pub fn write(&self, path: &Path) {
        let f = hdf5::File::create(path).unwrap();
        let h = f.create_group("Header").unwrap();
        for (name, v) in &self.header {
            if *name == "Dimension" {
                h.new_attr::<i32>()
                    .create(*name)
                    .unwrap()
                    .write_scalar(&(v[0] as i32))
                    .unwrap();
            } else {
                h.new_attr_builder()
                    .with_data(v.as_slice())
                    .create(*name)
                    .unwrap();
            }
        }
        for (gname, cols) in &self.groups {
            let g = f.create_group(gname).unwrap();
            for (name, c) in cols {
                match c {
                    Column::F(v, w) => {
                        let shape = if *w == 1 {
                            vec![v.len()]
                        } else {
                            vec![v.len() / w, *w]
                        };
                        let a = ndarray::ArrayD::from_shape_vec(shape, v.clone()).unwrap();
                        g.new_dataset_builder().with_data(&a).create(*name).unwrap();
                    }
                    Column::I(v) => {
                        g.new_dataset_builder()
                            .with_data(v.as_slice())
                            .create(*name)
                            .unwrap();
                    }
                }
            }
        }
    }
}

/// A scene in `dir` that takes its particles from `ics` (relative to `dir`), with the
/// sections that follow.
pub fn file_scene(dir: &Path, dim: u32, ics: &str, periodic: &str, rest: &str) -> LoadedScene {
    let text = format!(
        "[scene]\nname = \"from_file\"\nproblem = \"file\"\ndim = {dim}\n\n[file]\npath = \"{ics}\"\n\
         periodic = {periodic}\n\n{rest}"
    );
    let path = dir.join("scene.toml");
    std::fs::write(&path, &text).unwrap();
    dustsph::scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"))
}

pub fn run_in(dir: &Path, loaded: &LoadedScene, out: &str) -> (dustsph::sim::run::Summary, State) {
    let opts = dustsph::sim::run::RunOptions::quiet_on_cpu(dir.join(out));
    dustsph::sim::run::run(loaded, &opts).unwrap_or_else(|e| panic!("{e}"))
}
