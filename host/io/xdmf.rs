//! XDMF (`.xmf`) sidecars so that ParaView (VTK's `vtkXdmfReader`) opens snapshots, following
//! SWIFT's convention: one `Grid` per particle phase (gas from `PartType0`, dust from
//! `PartType3`) with `Polyvertex` topology, `XYZ` geometry from `Coordinates`, and every other
//! dataset as a node attribute whose `DataItem` points into the HDF5 file
//! (`snapshot_NNNN.h5:/PartTypeN/Name`, by file name, so the pair can be moved together).
//!
//! A per-snapshot file is a spatial collection of the phase grids at one time;
//! `snapshots.xmf` ([`write_xdmf_series`]) is a temporal collection that pulls the phase grids of
//! each snapshot's sidecar in with XInclude, one `Time` per entry.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::snapshot::{
    COORDINATES, DENSITY, DUST_GROUP, FRACTION_INDEX, GAS_GROUP, INTERNAL_ENERGY, MASSES,
    PARTICLE_IDS, PRESSURE, SMOOTHING_LENGTH, STOPPING_TIME, VELOCITIES,
};
use super::{write_bytes_atomic, IoError, PhaseData, PhaseView, SnapshotData, SnapshotView};

/// File name of the time-series sidecar.
pub const SERIES_NAME: &str = "snapshots.xmf";

/// The element type of a dataset, as XDMF names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Number {
    /// f64.
    Float8,
    /// u64 in the file, declared as a signed 64-bit integer: VTK's XDMF reader reads
    /// `UInt`/8 as a 32-bit integer and saturates larger values, while `Int`/8 reads back
    /// exactly (HDF5 converts; particle IDs stay below 2^63).
    UInt8AsInt8,
    /// u32.
    UInt4,
}

impl Number {
    fn xdmf(self) -> (&'static str, u32) {
        match self {
            Number::Float8 => ("Float", 8),
            Number::UInt8AsInt8 => ("Int", 8),
            Number::UInt4 => ("UInt", 4),
        }
    }
}

/// One dataset of a particle group: its name, values per particle (1 or 3) and element type.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Column {
    pub name: &'static str,
    pub width: usize,
    pub number: Number,
}

/// What one particle group of a snapshot file holds.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct GroupLayout {
    /// Grid name shown in ParaView.
    pub label: &'static str,
    /// HDF5 group.
    pub group: &'static str,
    pub n: u64,
    /// Attribute datasets (not the coordinates), in file order.
    pub columns: Vec<Column>,
}

const fn col(name: &'static str, width: usize, number: Number) -> Column {
    Column {
        name,
        width,
        number,
    }
}

/// The columns [`super::write_snapshot`] writes for a group with the given optional fields.
fn columns(e: bool, p: bool, fraction: bool, t_stop: bool) -> Vec<Column> {
    let mut c = vec![
        col(VELOCITIES, 3, Number::Float8),
        col(MASSES, 1, Number::Float8),
        col(DENSITY, 1, Number::Float8),
    ];
    if e {
        c.push(col(INTERNAL_ENERGY, 1, Number::Float8));
    }
    if p {
        c.push(col(PRESSURE, 1, Number::Float8));
    }
    c.push(col(SMOOTHING_LENGTH, 1, Number::Float8));
    c.push(col(PARTICLE_IDS, 1, Number::UInt8AsInt8));
    if fraction {
        c.push(col(FRACTION_INDEX, 1, Number::UInt4));
    }
    if t_stop {
        c.push(col(STOPPING_TIME, 1, Number::Float8));
    }
    c
}

fn layout_of_data(label: &'static str, group: &'static str, ph: &PhaseData) -> GroupLayout {
    GroupLayout {
        label,
        group,
        n: ph.x.len() as u64,
        columns: columns(
            ph.e.is_some(),
            ph.p.is_some(),
            ph.fraction.is_some(),
            ph.t_stop.is_some(),
        ),
    }
}

/// The groups of a snapshot file, as read back.
fn layout_of_snapshot(snap: &SnapshotData) -> Vec<GroupLayout> {
    let mut out = Vec::new();
    if let Some(g) = &snap.gas {
        out.push(layout_of_data("gas", GAS_GROUP, g));
    }
    if let Some(d) = &snap.dust {
        out.push(layout_of_data("dust", DUST_GROUP, d));
    }
    out
}

/// The groups [`super::write_snapshot`] writes for a view: the dust fractions concatenated, with
/// `FractionIndex` always and `StoppingTime` when any fraction has one.
fn layout_of_view(snap: &SnapshotView) -> Vec<GroupLayout> {
    let mut out = Vec::new();
    if let Some(g) = &snap.gas {
        out.push(GroupLayout {
            label: "gas",
            group: GAS_GROUP,
            n: g.len() as u64,
            columns: columns(g.e.is_some(), g.p.is_some(), false, g.t_stop.is_some()),
        });
    }
    if !snap.dust.is_empty() {
        out.push(GroupLayout {
            label: "dust",
            group: DUST_GROUP,
            n: snap.dust.iter().map(PhaseView::len).sum::<usize>() as u64,
            columns: columns(
                false,
                false,
                true,
                snap.dust.iter().any(|d| d.t_stop.is_some()),
            ),
        });
    }
    out
}

/// The sidecar of an HDF5 snapshot: the same path with extension `.xmf`.
pub fn xdmf_path(h5_path: &Path) -> PathBuf {
    h5_path.with_extension("xmf")
}

/// Escapes text for an XML attribute value or element content.
fn xml_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

/// The bare file name of `path` as UTF-8, usable in an XDMF `file:/dataset` reference.
fn file_name_of(path: &Path) -> Result<&str, IoError> {
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| IoError::invalid(path, "not a UTF-8 file name"))?;
    // XDMF splits "file:/dataset" at the first colon.
    if name.contains(':') {
        return Err(IoError::invalid(
            path,
            "an XDMF reference cannot name a file whose name contains ':'",
        ));
    }
    Ok(name)
}

fn check_time(path: &Path, t: f64) -> Result<(), IoError> {
    if t.is_finite() {
        Ok(())
    } else {
        Err(IoError::invalid(path, format!("time {t} is not finite")))
    }
}

// No `<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd">`: readers do not need it, and libxml2 warns that it
// cannot load the DTD for every file it pulls in by XInclude.
const XML_HEAD: &str = "<?xml version=\"1.0\" encoding=\"utf-8\"?>\n\
<Xdmf xmlns:xi=\"http://www.w3.org/2001/XInclude\" Version=\"2.0\">\n  <Domain>\n";
const XML_TAIL: &str = "  </Domain>\n</Xdmf>\n";

/// One `DataItem` referencing `h5:/group/name`.
fn data_item(out: &mut String, indent: &str, h5: &str, group: &str, n: u64, c: &Column) {
    let dims = if c.width == 1 {
        n.to_string()
    } else {
        format!("{n} {}", c.width)
    };
    let (ty, prec) = c.number.xdmf();
    writeln!(
        out,
        "{indent}<DataItem Dimensions=\"{dims}\" NumberType=\"{ty}\" Precision=\"{prec}\" \
         Format=\"HDF\">{}:/{group}/{}</DataItem>",
        xml_escape(h5),
        c.name
    )
    .expect("writing to a String cannot fail");
}

/// The XML of one snapshot's sidecar. Empty groups get no grid (a zero-point grid trips some
/// readers).
pub(crate) fn snapshot_xml(
    h5_name: &str,
    grid_name: &str,
    time: f64,
    groups: &[GroupLayout],
) -> String {
    let mut s = String::from(XML_HEAD);
    let w = |s: &mut String, line: String| {
        s.push_str(&line);
        s.push('\n');
    };
    w(
        &mut s,
        format!(
            "    <Grid Name=\"{}\" GridType=\"Collection\" CollectionType=\"Spatial\">",
            xml_escape(grid_name)
        ),
    );
    w(&mut s, format!("      <Time Value=\"{time}\"/>"));
    for g in groups.iter().filter(|g| g.n > 0) {
        w(
            &mut s,
            format!("      <Grid Name=\"{}\" GridType=\"Uniform\">", g.label),
        );
        w(
            &mut s,
            format!(
                "        <Topology TopologyType=\"Polyvertex\" NumberOfElements=\"{}\"/>",
                g.n
            ),
        );
        w(&mut s, "        <Geometry GeometryType=\"XYZ\">".into());
        let coords = col(COORDINATES, 3, Number::Float8);
        data_item(&mut s, "          ", h5_name, g.group, g.n, &coords);
        w(&mut s, "        </Geometry>".into());
        for c in &g.columns {
            let kind = if c.width == 3 { "Vector" } else { "Scalar" };
            w(
                &mut s,
                format!(
                    "        <Attribute Name=\"{}\" AttributeType=\"{kind}\" Center=\"Node\">",
                    c.name
                ),
            );
            data_item(&mut s, "          ", h5_name, g.group, g.n, c);
            w(&mut s, "        </Attribute>".into());
        }
        w(&mut s, "      </Grid>".into());
    }
    w(&mut s, "    </Grid>".into());
    s.push_str(XML_TAIL);
    s
}

fn write_sidecar(h5_path: &Path, time: f64, groups: &[GroupLayout]) -> Result<(), IoError> {
    check_time(h5_path, time)?;
    let h5_name = file_name_of(h5_path)?;
    let stem = Path::new(h5_name)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or(h5_name);
    let xml = snapshot_xml(h5_name, stem, time, groups);
    write_bytes_atomic(&xdmf_path(h5_path), xml.as_bytes())
}

/// Writes the sidecar of the snapshot file `h5_path` (`h5_path` with extension `.xmf`, next to
/// it, atomically). `snap` must describe that file, e.g. as [`super::read_snapshot`] returns it:
/// the datasets it names are the ones `snap` holds.
pub fn write_xdmf(h5_path: &Path, snap: &SnapshotData) -> Result<(), IoError> {
    write_sidecar(h5_path, snap.time, &layout_of_snapshot(snap))
}

/// As [`write_xdmf`], from the view that [`super::write_snapshot`] wrote to `h5_path` (no need
/// to read the file back).
pub fn write_xdmf_view(h5_path: &Path, snap: &SnapshotView) -> Result<(), IoError> {
    write_sidecar(h5_path, snap.time, &layout_of_view(snap))
}

/// [`write_xdmf_view`] of a snapshot written by share ([`super::write_snapshot_shared`]):
/// `snap` is one process's share, `rows` the gas's and the dust's rows in the file.
pub fn write_xdmf_view_rows(
    h5_path: &Path,
    snap: &SnapshotView,
    rows: [u64; 2],
) -> Result<(), IoError> {
    let mut layout = layout_of_view(snap);
    for g in &mut layout {
        g.n = if g.group == GAS_GROUP {
            rows[0]
        } else {
            rows[1]
        };
    }
    write_sidecar(h5_path, snap.time, &layout)
}

/// Writes `dir/snapshots.xmf` atomically: a temporal collection with one member per entry
/// `(time, file)`, in the given order. `file` names a snapshot in `dir` (`snapshot_0003.h5`) or
/// its sidecar (`snapshot_0003.xmf`); the member takes the phase grids of the sidecar (which must
/// exist when a reader opens the series) by XInclude and carries the entry's time.
pub fn write_xdmf_series(dir: &Path, entries: &[(f64, String)]) -> Result<(), IoError> {
    let path = dir.join(SERIES_NAME);
    let mut s = String::from(XML_HEAD);
    s.push_str(
        "    <Grid Name=\"snapshots\" GridType=\"Collection\" CollectionType=\"Temporal\">\n",
    );
    for (t, file) in entries {
        check_time(&path, *t)?;
        let xmf = xdmf_path(Path::new(file));
        if xmf.parent().is_some_and(|p| !p.as_os_str().is_empty()) {
            return Err(IoError::invalid(
                &path,
                format!("series entry '{file}' must be a file name in the same directory"),
            ));
        }
        let name = file_name_of(&xmf)?;
        let stem = xmf.file_stem().and_then(|s| s.to_str()).unwrap_or(name);
        writeln!(
            s,
            "      <Grid Name=\"{}\" GridType=\"Collection\" CollectionType=\"Spatial\">\n        \
             <Time Value=\"{t}\"/>\n        \
             <xi:include href=\"{}\" xpointer=\"xpointer(/Xdmf/Domain/Grid/Grid)\"/>\n      \
             </Grid>",
            xml_escape(stem),
            xml_escape(name)
        )
        .expect("writing to a String cannot fail");
    }
    s.push_str("    </Grid>\n");
    s.push_str(XML_TAIL);
    write_bytes_atomic(&path, s.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::{read_snapshot, write_snapshot};
    use hdf5::types::{FloatSize, IntSize, TypeDescriptor};
    use std::collections::BTreeMap;
    use std::fs;

    /// An element of a parsed XML document.
    #[derive(Debug, Default)]
    struct Element {
        name: String,
        attrs: BTreeMap<String, String>,
        text: String,
        children: Vec<Element>,
    }

    impl Element {
        fn walk<'a>(&'a self, out: &mut Vec<&'a Element>) {
            out.push(self);
            for c in &self.children {
                c.walk(out);
            }
        }

        fn all(&self, name: &str) -> Vec<&Element> {
            let mut v = Vec::new();
            self.walk(&mut v);
            v.retain(|e| e.name == name);
            v
        }

        fn kids(&self, name: &str) -> Vec<&Element> {
            self.children.iter().filter(|e| e.name == name).collect()
        }
    }

    /// The document as `Element`s, parsed by roxmltree (which refuses malformed XML:
    /// unbalanced or mismatched tags, unquoted or duplicate attributes, bare '&' or '<').
    fn parse_xml(src: &str) -> Element {
        // Names as written ("xi:include"), namespace declarations as attributes.
        fn conv(n: roxmltree::Node) -> Element {
            let local = n.tag_name().name();
            let name = match n.tag_name().namespace().and_then(|u| n.lookup_prefix(u)) {
                Some(p) if !p.is_empty() => format!("{p}:{local}"),
                _ => local.to_string(),
            };
            let mut attrs: BTreeMap<String, String> = n
                .attributes()
                .map(|a| (a.name().to_string(), a.value().to_string()))
                .collect();
            if n.parent().is_some_and(|p| p.is_root()) {
                for ns in n.namespaces() {
                    let key = ns.name().map_or("xmlns".into(), |p| format!("xmlns:{p}"));
                    attrs.insert(key, ns.uri().to_string());
                }
            }
            Element {
                name,
                attrs,
                text: n
                    .children()
                    .filter(|c| c.is_text())
                    .filter_map(|c| c.text())
                    .collect(),
                children: n.children().filter(|c| c.is_element()).map(conv).collect(),
            }
        }
        let opt = roxmltree::ParsingOptions {
            allow_dtd: true,
            ..Default::default()
        };
        let doc = roxmltree::Document::parse_with_options(src, opt)
            .unwrap_or_else(|e| panic!("malformed XML: {e}"));
        conv(doc.root_element())
    }

    struct Phase {
        x: Vec<[f64; 3]>,
        m: Vec<f64>,
        id: Vec<u64>,
        t: Vec<f64>,
    }

    impl Phase {
        fn new(n: usize, seed: u64) -> Phase {
            Phase {
                x: (0..n)
                    .map(|i| [i as f64, seed as f64, 0.5 * i as f64])
                    .collect(),
                m: (0..n).map(|i| 1.0 + i as f64).collect(),
                id: (0..n as u64).map(|i| 1000 * seed + i).collect(),
                t: (0..n)
                    .map(|i| if i == 0 { f64::INFINITY } else { 1e-3 })
                    .collect(),
            }
        }

        fn view(&self, gas: bool) -> PhaseView<'_> {
            PhaseView {
                x: &self.x,
                v: &self.x,
                m: &self.m,
                rho: &self.m,
                h: 0.1,
                h_each: None,
                id: &self.id,
                e: gas.then_some(&self.m[..]),
                p: gas.then_some(&self.m[..]),
                t_stop: (!gas).then_some(&self.t[..]),
            }
        }
    }

    fn view<'a>(gas: Option<PhaseView<'a>>, dust: Vec<PhaseView<'a>>) -> SnapshotView<'a> {
        SnapshotView {
            time: 0.2,
            dim: 3,
            periodic: [None; 3],
            pad: 0.5,
            scene_text: "",
            scene_model: "",
            source: Default::default(),
            gas,
            dust,
        }
    }

    /// Checks a parsed sidecar against the HDF5 file it names: every referenced dataset exists
    /// with the stated shape and element type; returns the grids' (name, point count).
    fn check_against_file(xml: &Element, dir: &Path) -> Vec<(String, u64)> {
        assert_eq!(xml.name, "Xdmf");
        let mut grids = Vec::new();
        for g in xml.all("Grid") {
            if g.attrs["GridType"] != "Uniform" {
                continue;
            }
            let topo = g.kids("Topology");
            assert_eq!(topo.len(), 1);
            assert_eq!(topo[0].attrs["TopologyType"], "Polyvertex");
            let n: u64 = topo[0].attrs["NumberOfElements"].parse().unwrap();
            let geo = g.kids("Geometry");
            assert_eq!(geo.len(), 1);
            assert_eq!(geo[0].attrs["GeometryType"], "XYZ");
            let items = g.all("DataItem");
            assert_eq!(items.len(), 1 + g.kids("Attribute").len());
            for item in items {
                assert_eq!(item.attrs["Format"], "HDF");
                let (file, ds_path) = item.text.trim().split_once(':').unwrap();
                assert!(!file.contains('/'), "reference by file name: {file}");
                let f = hdf5::File::open(dir.join(file)).unwrap();
                let ds = f
                    .dataset(ds_path)
                    .unwrap_or_else(|e| panic!("{ds_path}: {e}"));
                let dims: Vec<usize> = item.attrs["Dimensions"]
                    .split_whitespace()
                    .map(|d| d.parse().unwrap())
                    .collect();
                assert_eq!(ds.shape(), dims, "{ds_path}");
                assert_eq!(dims[0] as u64, n, "{ds_path}");
                let ty = ds.dtype().unwrap().to_descriptor().unwrap();
                let want = match (
                    item.attrs["NumberType"].as_str(),
                    item.attrs["Precision"].as_str(),
                ) {
                    ("Float", "8") => TypeDescriptor::Float(FloatSize::U8),
                    // ParticleIDs: u64 in the file, read as i64 (see `Number`).
                    ("Int", "8") if ds_path.ends_with("/ParticleIDs") => {
                        TypeDescriptor::Unsigned(IntSize::U8)
                    }
                    ("UInt", "4") => TypeDescriptor::Unsigned(IntSize::U4),
                    other => panic!("unexpected type {other:?}"),
                };
                assert_eq!(ty, want, "{ds_path}");
            }
            grids.push((g.attrs["Name"].clone(), n));
        }
        grids
    }

    fn attribute_names(xml: &Element, grid: &str) -> Vec<String> {
        let g = xml
            .all("Grid")
            .into_iter()
            .find(|g| g.attrs["Name"] == grid)
            .unwrap();
        g.kids("Attribute")
            .iter()
            .map(|a| a.attrs["Name"].clone())
            .collect()
    }

    #[test]
    fn sidecar_is_well_formed_and_names_datasets_that_exist() {
        let dir = tempfile::tempdir().unwrap();
        let h5 = dir.path().join("snapshot_0003.h5");
        let (g, d0, d1) = (Phase::new(5, 1), Phase::new(2, 2), Phase::new(3, 3));
        let v = view(Some(g.view(true)), vec![d0.view(false), d1.view(false)]);
        write_snapshot(&h5, &v).unwrap();
        let snap = read_snapshot(&h5).unwrap();
        write_xdmf(&h5, &snap).unwrap();
        let text = fs::read_to_string(dir.path().join("snapshot_0003.xmf")).unwrap();
        let xml = parse_xml(&text);
        let grids = check_against_file(&xml, dir.path());
        assert_eq!(grids, vec![("gas".into(), 5), ("dust".into(), 5)]);
        assert_eq!(
            attribute_names(&xml, "gas"),
            [
                "Velocities",
                "Masses",
                "Density",
                "InternalEnergy",
                "Pressure",
                "SmoothingLength",
                "ParticleIDs"
            ]
        );
        assert_eq!(
            attribute_names(&xml, "dust"),
            [
                "Velocities",
                "Masses",
                "Density",
                "SmoothingLength",
                "ParticleIDs",
                "FractionIndex",
                "StoppingTime"
            ]
        );
        // Velocities is a vector; the collection carries the time.
        let vel = xml
            .all("Attribute")
            .into_iter()
            .find(|a| a.attrs["Name"] == "Velocities")
            .unwrap();
        assert_eq!(vel.attrs["AttributeType"], "Vector");
        let top = &xml.kids("Domain")[0].kids("Grid")[0];
        assert_eq!(top.attrs["CollectionType"], "Spatial");
        assert_eq!(top.attrs["Name"], "snapshot_0003");
        let t: f64 = top.kids("Time")[0].attrs["Value"].parse().unwrap();
        assert_eq!(t, 0.2);
        // The view gives the same file as the data read back.
        fs::remove_file(dir.path().join("snapshot_0003.xmf")).unwrap();
        write_xdmf_view(&h5, &v).unwrap();
        let again = fs::read_to_string(dir.path().join("snapshot_0003.xmf")).unwrap();
        assert_eq!(again, text);
        // Only the snapshot and its sidecar are there.
        let mut names: Vec<_> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["snapshot_0003.h5", "snapshot_0003.xmf"]);
    }

    #[test]
    fn optional_and_empty_groups() {
        let dir = tempfile::tempdir().unwrap();
        // Gas without pressure; an empty dust group (no grid); a snapshot with one phase only.
        let (g, empty) = (Phase::new(4, 1), Phase::new(0, 0));
        let mut gv = g.view(true);
        gv.p = None;
        let h5 = dir.path().join("a.h5");
        let v = view(Some(gv), vec![empty.view(false)]);
        write_snapshot(&h5, &v).unwrap();
        write_xdmf(&h5, &read_snapshot(&h5).unwrap()).unwrap();
        let xml = parse_xml(&fs::read_to_string(dir.path().join("a.xmf")).unwrap());
        assert_eq!(
            check_against_file(&xml, dir.path()),
            vec![("gas".into(), 4)]
        );
        assert!(!attribute_names(&xml, "gas").contains(&"Pressure".to_string()));
        let text_view = snapshot_xml("a.h5", "a", 0.2, &layout_of_view(&v));
        assert_eq!(
            text_view,
            fs::read_to_string(dir.path().join("a.xmf")).unwrap()
        );

        let d = Phase::new(3, 2);
        let mut dv = d.view(false);
        dv.t_stop = None;
        let h5 = dir.path().join("b.h5");
        write_snapshot(&h5, &view(None, vec![dv])).unwrap();
        write_xdmf(&h5, &read_snapshot(&h5).unwrap()).unwrap();
        let xml = parse_xml(&fs::read_to_string(dir.path().join("b.xmf")).unwrap());
        assert_eq!(
            check_against_file(&xml, dir.path()),
            vec![("dust".into(), 3)]
        );
        assert!(!attribute_names(&xml, "dust").contains(&"StoppingTime".to_string()));
    }

    #[test]
    fn names_are_escaped_and_bad_input_is_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let g = Phase::new(2, 1);
        let h5 = dir.path().join("r&d <1>.h5");
        let v = view(Some(g.view(true)), vec![]);
        write_snapshot(&h5, &v).unwrap();
        write_xdmf_view(&h5, &v).unwrap();
        let xml = parse_xml(&fs::read_to_string(dir.path().join("r&d <1>.xmf")).unwrap());
        assert_eq!(
            check_against_file(&xml, dir.path()),
            vec![("gas".into(), 2)]
        );

        let err = write_xdmf_view(&dir.path().join("a:b.h5"), &v).unwrap_err();
        assert!(err.to_string().contains("':'"), "{err}");
        let mut bad = v.clone();
        bad.time = f64::NAN;
        assert!(write_xdmf_view(&h5, &bad).is_err());
        let err =
            write_xdmf_series(dir.path(), &[(0.0, "sub/snapshot_0000.h5".into())]).unwrap_err();
        assert!(err.to_string().contains("same directory"), "{err}");
        assert!(!dir.path().join(SERIES_NAME).exists());
    }

    #[test]
    fn series_is_a_temporal_collection_including_each_sidecar() {
        let dir = tempfile::tempdir().unwrap();
        let mut entries = Vec::new();
        for (i, t) in [0.0, 0.1, 0.2].into_iter().enumerate() {
            let (g, d) = (Phase::new(3 + i, 1), Phase::new(2, 2));
            let mut v = view(Some(g.view(true)), vec![d.view(false)]);
            v.time = t;
            let name = crate::io::snapshot_name(i);
            let h5 = dir.path().join(&name);
            write_snapshot(&h5, &v).unwrap();
            write_xdmf_view(&h5, &v).unwrap();
            entries.push((t, name));
        }
        // Either the snapshot's name or its sidecar's is accepted.
        entries[2].1 = "snapshot_0002.xmf".into();
        write_xdmf_series(dir.path(), &entries).unwrap();
        let xml = parse_xml(&fs::read_to_string(dir.path().join(SERIES_NAME)).unwrap());
        assert_eq!(xml.attrs["xmlns:xi"], "http://www.w3.org/2001/XInclude");
        let top = &xml.kids("Domain")[0].kids("Grid")[0];
        assert_eq!(top.attrs["GridType"], "Collection");
        assert_eq!(top.attrs["CollectionType"], "Temporal");
        let members = top.kids("Grid");
        assert_eq!(members.len(), 3);
        for (k, m) in members.iter().enumerate() {
            let t: f64 = m.kids("Time")[0].attrs["Value"].parse().unwrap();
            assert_eq!(t, entries[k].0);
            let inc = m.kids("xi:include");
            assert_eq!(inc.len(), 1);
            let href = &inc[0].attrs["href"];
            assert_eq!(href, &format!("snapshot_{k:04}.xmf"));
            // The included file exists and has the phase grids the xpointer selects.
            let sub = parse_xml(&fs::read_to_string(dir.path().join(href)).unwrap());
            let phases = sub.kids("Domain")[0].kids("Grid")[0].kids("Grid");
            assert_eq!(phases.len(), 2);
            assert_eq!(
                check_against_file(&sub, dir.path()),
                vec![("gas".into(), 3 + k as u64), ("dust".into(), 2)]
            );
        }
    }
}
