//! Scene files: TOML → the resolved [`Scene`] model.
//!
//! Three layers: the file as written ([`file`]: serde structs mirroring the TOML), its checks
//! and defaults (`resolve.rs`: [`Scene::from_file`]), and the model every run is made of
//! ([`model`]: enums in place of the file's optional keys). Every key is checked before any
//! output is written. Errors name the file and the dotted key (`gas.gamma`,
//! `dust.fractions.1.t_stop`, ...). `--set key=value` overrides are applied to the parsed table
//! before validation, so they are checked exactly like file keys.
pub mod file;
pub mod model;
mod overrides;
mod resolve;

pub use file::*;
pub use model::*;
pub use overrides::apply_override;
pub use resolve::{num, MAX_FIXED_STEPS};

use std::fmt;
use std::path::{Path, PathBuf};

/// A scene error: which file, which key, what is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    pub file: PathBuf,
    pub key: Option<String>,
    pub msg: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.key {
            Some(k) => write!(f, "{}: key `{}`: {}", self.file.display(), k, self.msg),
            None => write!(f, "{}: {}", self.file.display(), self.msg),
        }
    }
}

impl std::error::Error for SceneError {}

/// A scene as loaded: the validated settings and how they were made (the file, its verbatim
/// text, the `--set` overrides, and the effective scene: the file's table with the overrides
/// applied, as TOML). Every output records all four; readers parse the effective scene.
#[derive(Debug, Clone)]
pub struct LoadedScene {
    pub scene: Scene,
    pub path: PathBuf,
    pub text: String,
    pub overrides: Vec<String>,
    /// The scene as run: [`effective_text`] of `text` and `overrides`.
    pub effective: String,
}

impl LoadedScene {
    /// A scene from its text and overrides (`file` names it in messages and outputs).
    pub fn from_text(
        text: &str,
        file: &Path,
        overrides: &[String],
    ) -> Result<LoadedScene, SceneError> {
        let scene = parse(text, file, overrides)?;
        Ok(LoadedScene {
            scene,
            path: file.to_path_buf(),
            text: text.to_string(),
            overrides: overrides.to_vec(),
            effective: effective_text(text, file, overrides)?,
        })
    }

    /// `numerics.precision` set by a command-line option: the model's field, and the
    /// option recorded as the override `numerics.precision="…"` (the last, so it wins over a
    /// `--set` of the same key), so that the effective scene still says what ran.
    pub fn set_precision(&mut self, p: Precision) -> Result<(), SceneError> {
        self.record_option("numerics.precision", p.name())?;
        self.scene.numerics.precision = p;
        Ok(())
    }

    /// The command line's numerics options (`--precision`, `--neighbour-list`), where given,
    /// set on the scene ([`Self::set_precision`]).
    pub fn with_numerics(
        mut self,
        precision: Option<Precision>,
        list: Option<ListChoice>,
    ) -> Result<LoadedScene, SceneError> {
        if let Some(p) = precision {
            self.set_precision(p)?;
        }
        if let Some(l) = list {
            self.set_neighbour_list(l)?;
        }
        Ok(self)
    }

    /// `numerics.neighbour_list` set by a command-line option, as [`Self::set_precision`].
    pub fn set_neighbour_list(&mut self, l: ListChoice) -> Result<(), SceneError> {
        self.record_option("numerics.neighbour_list", l.name())?;
        self.scene.numerics.neighbour_list = l;
        Ok(())
    }

    /// A command-line option's string value as the last override, and the effective scene
    /// made again with it.
    fn record_option(&mut self, key: &str, value: &str) -> Result<(), SceneError> {
        let mut overrides = self.overrides.clone();
        overrides.push(format!("{key}=\"{value}\""));
        self.effective = effective_text(&self.text, &self.path, &overrides)?;
        self.overrides = overrides;
        Ok(())
    }
}

/// The effective scene: the file's TOML table with every `--set` override applied, written
/// back as TOML (comments and key order of the file are not kept; every value is, to the bit:
/// TOML floats are written in their shortest round-trip form). Parsing it without overrides
/// gives the same scene as parsing `text` with them.
pub fn effective_text(text: &str, file: &Path, overrides: &[String]) -> Result<String, SceneError> {
    let table = overridden_table(text, file, overrides)?;
    toml::to_string(&table).map_err(|e| SceneError {
        file: file.to_path_buf(),
        key: None,
        msg: format!("cannot be written back as TOML: {e}"),
    })
}

/// The scene text's TOML table with the `--set` overrides applied.
fn overridden_table(
    text: &str,
    file: &Path,
    overrides: &[String],
) -> Result<toml::Table, SceneError> {
    let err = |key: Option<String>, msg: String| SceneError {
        file: file.to_path_buf(),
        key,
        msg,
    };
    let mut table: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| err(None, format!("not valid TOML: {e}")))?;
    for ov in overrides {
        apply_override(&mut table, ov).map_err(|(key, msg)| err(key, msg))?;
    }
    Ok(table)
}

/// Every section of a scene is a table, and so is every `[[dust.fractions]]` entry: serde would
/// otherwise read an array (`idic = [0.5]`) into the section's fields by position.
fn check_tables(root: &toml::Table) -> Result<(), (String, String)> {
    let not_table = |key: &str, v: &toml::Value| {
        (
            key.to_string(),
            format!(
                "must be a table (a [section] of key = value lines, or {{ key = value, … }}), not {} {v}",
                match v {
                    toml::Value::Array(_) => "the array",
                    _ => "the value",
                }
            ),
        )
    };
    for (k, v) in root {
        let Some(t) = v.as_table() else {
            return Err(not_table(k, v));
        };
        if k == "dust" {
            if let Some(toml::Value::Array(fr)) = t.get("fractions") {
                for (i, f) in fr.iter().enumerate() {
                    if !f.is_table() {
                        return Err(not_table(&format!("dust.fractions.{i}"), f));
                    }
                }
            }
        }
    }
    Ok(())
}

/// Read, override and validate a scene file.
pub fn load(path: &Path, overrides: &[String]) -> Result<LoadedScene, SceneError> {
    let text = std::fs::read_to_string(path).map_err(|e| SceneError {
        file: path.to_path_buf(),
        key: None,
        msg: format!("cannot read scene file: {e}"),
    })?;
    LoadedScene::from_text(&text, path, overrides)
}

/// The shipped scenes, compiled in, so that `bench` and `parity` (which name them) run from
/// any directory.
const SHIPPED: [(&str, &str); 8] = [
    (
        "configs/dustybox.toml",
        include_str!("../../configs/dustybox.toml"),
    ),
    (
        "configs/dustywave.toml",
        include_str!("../../configs/dustywave.toml"),
    ),
    (
        "configs/dustyshock.toml",
        include_str!("../../configs/dustyshock.toml"),
    ),
    (
        "configs/dusty_ball.toml",
        include_str!("../../configs/dusty_ball.toml"),
    ),
    (
        "configs/dustysettle.toml",
        include_str!("../../configs/dustysettle.toml"),
    ),
    (
        "configs/dustywave_phantom.toml",
        include_str!("../../configs/dustywave_phantom.toml"),
    ),
    (
        "configs/dustywave_phantom_poly.toml",
        include_str!("../../configs/dustywave_phantom_poly.toml"),
    ),
    (
        "configs/dustydisc.toml",
        include_str!("../../configs/dustydisc.toml"),
    ),
];

/// [`load`] for one of the shipped scenes (`configs/NAME.toml`) from the copy compiled in.
pub fn load_shipped(name: &str, overrides: &[String]) -> Result<LoadedScene, SceneError> {
    let Some((_, text)) = SHIPPED.iter().find(|(n, _)| *n == name) else {
        return load(Path::new(name), overrides);
    };
    LoadedScene::from_text(text, Path::new(name), overrides)
}

/// Keys with a default that some scenes do not use, and why a scene does not (None: used).
type Unused = fn(&Scene) -> Option<&'static str>;
const UNUSED_UNLESS: [(&str, Unused); 5] = [
    ("sph.alpha", unused_without_viscosity),
    ("sph.beta", unused_without_viscosity),
    ("dustywave.lattice", unused_in_1d),
    ("dustywave.layers", unused_in_1d),
    ("dustybox.lattice", unused_in_1d),
];

fn unused_without_viscosity(s: &Scene) -> Option<&'static str> {
    (s.sph.viscosity.is_none())
        .then_some("used only with artificial viscosity (sph.viscosity = true)")
}

fn unused_in_1d(s: &Scene) -> Option<&'static str> {
    (s.dim == 1).then_some("2D/3D only: a 1D run is a uniform line of particles")
}

/// Parse scene text (with `--set` overrides) and validate it; `file` is used in messages.
pub fn parse(text: &str, file: &Path, overrides: &[String]) -> Result<Scene, SceneError> {
    let err = |key: Option<String>, msg: String| SceneError {
        file: file.to_path_buf(),
        key,
        msg,
    };
    let folder = file.parent().unwrap_or(Path::new("")).to_path_buf();
    let table = overridden_table(text, file, overrides)?;
    check_tables(&table).map_err(|(key, msg)| err(Some(key), msg))?;
    // Another problem's section (a stray `--set dustybox.length=1` on a wave): said before the
    // section's own missing keys would be.
    if let Some(problem) = table
        .get("scene")
        .and_then(|t| t.get("problem"))
        .and_then(|p| p.as_str())
    {
        let sections = [
            "dustybox",
            "dustywave",
            "dustyshock",
            "dustyball",
            "dustysettle",
            "file",
            "dustydisc",
        ];
        if sections.contains(&problem) {
            if let Some(other) = sections
                .iter()
                .find(|&&s| s != problem && table.contains_key(s))
            {
                return Err(err(
                    Some(other.to_string()),
                    format!("section [{other}] does not belong to problem `{problem}`"),
                ));
            }
        }
    }
    // Keys with defaults cannot tell "not given" after deserialising: note which were given
    // of those that some scenes do not use (checked after validation, below).
    let given: Vec<(&str, Unused)> = UNUSED_UNLESS
        .iter()
        .copied()
        .filter(|(k, _)| {
            k.split_once('.').is_some_and(|(section, key)| {
                table
                    .get(section)
                    .and_then(|t| t.as_table())
                    .is_some_and(|t| t.contains_key(key))
            })
        })
        .collect();
    let value = toml::Value::Table(table);
    let file: SceneFile = serde_path_to_error::deserialize(value).map_err(|e| {
        // serde writes sequence indices as `a[0].b`; scene keys are `a.0.b` everywhere.
        let path = e.path().to_string().replace('[', ".").replace(']', "");
        let key = if path == "." || path.is_empty() {
            None
        } else {
            Some(path)
        };
        let msg = e.into_inner().to_string();
        // toml appends its own, index-less location ("in `a.b`"); the key already says where.
        let msg = match msg.find("\nin `").or_else(|| msg.find(" in `")) {
            Some(i) => msg[..i].trim_end().to_string(),
            None => msg,
        };
        err(key, msg)
    })?;
    let mut scene = Scene::from_file(&file).map_err(|(key, msg)| err(Some(key), msg))?;
    // A file's initial conditions are found from the scene file's folder.
    if let ProblemCfg::File(f) = &mut scene.problem {
        f.resolved = folder.join(&f.path);
    }
    // A key given but not used would silently not do what its author meant.
    for (k, why) in given {
        if let Some(why) = why(&scene) {
            return Err(err(
                Some(k.to_string()),
                format!("{why} (remove it: --set {k}=)"),
            ));
        }
    }
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dustsph_device::drag::StoppingLaw;

    /// Every shipped scene: the model is written as TOML, and its effective scene parses back
    /// to the same model.
    #[test]
    fn shipped_scenes_write_their_model_and_parse_back() {
        for (name, _) in SHIPPED {
            let l = load_shipped(name, &[]).unwrap();
            let toml = l.scene.to_toml();
            assert!(toml.starts_with("[scene]\n"), "{name}:\n{toml}");
            assert!(!toml.contains("cannot be written"), "{name}:\n{toml}");
            let table: toml::Table = toml.parse().unwrap();
            assert!(table.contains_key(l.scene.kind().name()), "{name}:\n{toml}");
            let again = parse(&l.effective, Path::new(name), &[]).unwrap();
            assert_eq!(again, l.scene, "{name}");
        }
    }

    /// An option set on the model is recorded as an override: the effective scene parses to
    /// the model that runs.
    #[test]
    fn options_set_the_model_and_the_effective_scene_alike() {
        let mut l = load_shipped("configs/dustywave.toml", &["sph.n=16".into()]).unwrap();
        l.set_precision(Precision::F32).unwrap();
        l.set_neighbour_list(ListChoice::Off).unwrap();
        assert_eq!(l.scene.numerics.precision, Precision::F32);
        assert_eq!(l.scene.numerics.neighbour_list, ListChoice::Off);
        assert_eq!(
            l.overrides,
            [
                "sph.n=16",
                "numerics.precision=\"f32\"",
                "numerics.neighbour_list=\"off\""
            ]
        );
        assert_eq!(parse(&l.effective, &l.path, &[]).unwrap(), l.scene);
        assert!(l.scene.to_toml().contains("precision = \"f32\""));
    }

    /// The model says which rule each choice took, and what the file leaves to defaults.
    #[test]
    fn the_model_resolves_rules_and_defaults() {
        let sets = ["time.cfl=".to_string(), "time.dt=0.01".to_string()];
        let l = load_shipped("configs/dustywave.toml", &sets).unwrap();
        assert_eq!(l.scene.time.step, StepRule::Fixed { dt: 0.01 });
        let toml = l.scene.to_toml();
        assert!(toml.contains("\ndt = 0.01\n"), "{toml}");
        assert!(!toml.contains("cfl"), "{toml}");
        // dust.t_stop fills in for a fraction that gives none.
        let sets = ["dust.fractions.0.t_stop=".into(), "dust.t_stop=0.25".into()];
        let l = load_shipped("configs/dustybox.toml", &sets).unwrap();
        let laws: Vec<_> = l.scene.fractions().iter().map(|f| f.law).collect();
        assert_eq!(laws[0], StoppingLaw::ConstantTime { t_stop: 0.25 });
        assert_eq!(laws[1], StoppingLaw::ConstantTime { t_stop: 0.215443 });
        assert!(l.scene.to_toml().contains("t_stop = 0.25\n"));
        // The isothermal background's pressure is c_s² ρ; viscosity off is no viscosity.
        assert_eq!(l.scene.problem.background().map(|b| b.p), Some(1.0));
        assert_eq!(l.scene.sph.viscosity, None);
        // The kernel coupling by default; the nearest cell with the explicit baseline.
        assert_eq!(l.scene.idic.coupling, Coupling::Kernel);
        assert!(l.scene.to_toml().contains("coupling = \"kernel\""));
        let l = load_shipped(
            "configs/dustybox.toml",
            &["drag.method=\"explicit\"".into()],
        );
        assert_eq!(l.unwrap().scene.idic.coupling, Coupling::Cell);
        let l = load_shipped("configs/dusty_ball.toml", &[]).unwrap();
        assert_eq!(l.scene.idic.coupling, Coupling::Cell);
    }

    /// `numerics.rebalance_at`: the ranks' default 0.05, `inf` (never) kept in the model and
    /// its effective scene, a negative or NaN value refused naming the key.
    #[test]
    fn the_rebalance_threshold_is_a_scene_key() {
        let l = load_shipped("configs/dustywave.toml", &[]).unwrap();
        assert_eq!(l.scene.numerics.rebalance_at, 0.05);
        let sets = ["numerics.rebalance_at=inf".to_string()];
        let l = load_shipped("configs/dustywave.toml", &sets).unwrap();
        assert_eq!(l.scene.numerics.rebalance_at, f64::INFINITY);
        assert!(l.scene.to_toml().contains("rebalance_at = inf"));
        assert_eq!(parse(&l.effective, &l.path, &[]).unwrap(), l.scene);
        for bad in ["-0.1", "nan"] {
            let sets = [format!("numerics.rebalance_at={bad}")];
            let e = load_shipped("configs/dustywave.toml", &sets).unwrap_err();
            assert_eq!(e.key.as_deref(), Some("numerics.rebalance_at"), "{e}");
        }
    }
}
