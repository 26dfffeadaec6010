//! Particles hashed into cubic cells, for searches within each particle's own support
//! (variable h: supports differ tenfold across a disc, so no single grid cell fits all): the
//! time bins' neighbour limiter and the start's neighbour count.
use rustc_hash::FxHashMap;

pub struct SupportGrid {
    cell: f64,
    pub members: FxHashMap<[i64; 3], Vec<usize>>,
    /// 0 on an axis where every particle has the same coordinate (a 2D or 1D scene's unused
    /// axes): no cell beside the particle's along it holds one.
    walk: [i64; 3],
}

impl SupportGrid {
    /// The particles at `x` in cells of side `cell`.
    pub fn new(x: &[[f64; 3]], cell: f64) -> SupportGrid {
        let cell = cell.max(f64::MIN_POSITIVE);
        let flat = |k: usize| x.iter().all(|p| p[k] == x[0][k]);
        let mut g = SupportGrid {
            cell,
            members: FxHashMap::default(),
            walk: [0, 1, 2].map(|k| (!flat(k)) as i64),
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
        let [rx, ry, rz] = self.walk.map(|w| w * reach);
        let k = self.key(p);
        for dx in -rx..=rx {
            for dy in -ry..=ry {
                for dz in -rz..=rz {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The particles the walk offers within r are exactly those a brute-force search finds, in
    /// 3D and on a plane (z = 0: the walk skips the empty cells above and below), for supports
    /// of a fraction of the cell to several cells.
    #[test]
    fn cells_within_find_every_particle_within_r_and_only_those() {
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for plane in [false, true] {
            let x: Vec<[f64; 3]> = (0..2000)
                .map(|_| [rnd(), rnd(), if plane { 0.0 } else { rnd() }])
                .collect();
            let g = SupportGrid::new(&x, 0.07);
            for a in (0..x.len()).step_by(37) {
                let r = 0.02 + 0.2 * rnd();
                let mut found = Vec::new();
                g.cells_within(x[a], r, |_, m, _| {
                    for &b in m {
                        let d = dustsph_device::sub(x[b], x[a]);
                        if dustsph_device::dot(d, d) < r * r {
                            found.push(b);
                        }
                    }
                });
                found.sort();
                let brute: Vec<usize> = (0..x.len())
                    .filter(|&b| {
                        let d = dustsph_device::sub(x[b], x[a]);
                        dustsph_device::dot(d, d) < r * r
                    })
                    .collect();
                assert_eq!(found, brute, "plane {plane}, particle {a}, r {r}");
            }
        }
    }
}
