//! Particles hashed into cubic cells, for searches within each particle's own support
//! (variable h: supports differ tenfold across a disc, so no single grid cell fits all): the
//! time bins' neighbour limiter and the start's neighbour count.
use std::collections::HashMap;

pub struct SupportGrid {
    cell: f64,
    pub members: HashMap<[i64; 3], Vec<usize>>,
}

impl SupportGrid {
    /// The particles at `x` in cells of side `cell`.
    pub fn new(x: &[[f64; 3]], cell: f64) -> SupportGrid {
        let cell = cell.max(f64::MIN_POSITIVE);
        let mut g = SupportGrid {
            cell,
            members: HashMap::new(),
        };
        for (a, &p) in x.iter().enumerate() {
            g.members.entry(g.key(p)).or_default().push(a);
        }
        g
    }

    /// The cell holding `p`.
    pub fn key(&self, p: [f64; 3]) -> [i64; 3] {
        p.map(|c| (c / self.cell).floor() as i64)
    }

    /// Each non-empty cell that reaches within `r` of `p`: its key, its particles, and whether
    /// it lies wholly within `r` (then every particle in it does).
    pub fn cells_within(&self, p: [f64; 3], r: f64, mut f: impl FnMut([i64; 3], &[usize], bool)) {
        let reach = (r / self.cell).ceil() as i64;
        let k = self.key(p);
        for dx in -reach..=reach {
            for dy in -reach..=reach {
                for dz in -reach..=reach {
                    let c = [k[0] + dx, k[1] + dy, k[2] + dz];
                    let Some(m) = self.members.get(&c) else {
                        continue;
                    };
                    // Nearest and farthest distance² from p to the cell's box.
                    let (mut near, mut far) = (0.0, 0.0);
                    for i in 0..3 {
                        let (lo, hi) = (c[i] as f64 * self.cell, (c[i] + 1) as f64 * self.cell);
                        let gap = (lo - p[i]).max(p[i] - hi).max(0.0);
                        let span = (p[i] - lo).abs().max((hi - p[i]).abs());
                        (near, far) = (near + gap * gap, far + span * span);
                    }
                    if near < r * r {
                        f(c, m, far < r * r);
                    }
                }
            }
        }
    }
}
