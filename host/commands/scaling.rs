//! `dustsph scaling`: the multi-rank model of issue 14 from the decomposition code run on the
//! real particle distribution, without the physics (docs/scaling.md). For a ball and a slab of
//! N particles on lattices at ≈57 neighbours, the Morton partition over R ranks: particles and
//! halo per rank, peers, the bytes a step exchanges and what they cost on an interconnect.
use crate::decomp::{CellBox, Cells, Partition};

/// Bytes a ghost receives per step, and the exchanges a step takes (the named refreshes, and
/// the builds' share), as measured over 2 ranks on the Phantom slab `sph.n=128` (leapfrog,
/// variable h, IAD, f64: `summary.json` `rank_traffic`, 0.62 MB per step from each rank to
/// the other's ≈1 840 ghosts, a halo of 0.10 × 18 432, 133 exchanges in 20 steps;
/// docs/scaling.md "Measured costs"): the defaults of `--halo-bytes` and `--exchanges`.
pub const HALO_BYTES_F64: f64 = 340.0;
pub const EXCHANGES: f64 = 6.5;
/// The message latency assumed per peer and exchange.
pub const LATENCY_S: f64 = 2e-6;

/// One row of the model.
#[derive(Debug, Clone)]
pub struct Row {
    pub ranks: u32,
    pub per_rank: f64,
    pub imbalance: f64,
    pub halo_max: u64,
    pub halo_mean: f64,
    pub peers_max: u32,
    /// Communication time per step on the slowest rank at `bandwidth` bytes/s.
    pub comm_s: f64,
}

/// The geometries: a ball of radius 1 (open) and Phantom's slab 1 × 0.32 × 0.27 (periodic),
/// simple cubic lattices of spacing Δ with N points, h = 1.2 Δ, reach 2h.
/// `depth`: the halo's depth in kernel supports (the cells of the cut are this wide).
pub fn cloud(kind: &str, n: f64, depth: f64) -> (CellBox, Box<dyn Iterator<Item = [f64; 3]>>) {
    match kind {
        "ball" => {
            let d = (4.0 * std::f64::consts::PI / (3.0 * n)).cbrt();
            let m = (1.0 / d).ceil() as i64;
            let pts = (-m..=m).flat_map(move |i| {
                (-m..=m).flat_map(move |j| {
                    (-m..=m).filter_map(move |k| {
                        let p = [i as f64 * d, j as f64 * d, k as f64 * d];
                        (p[0] * p[0] + p[1] * p[1] + p[2] * p[2] <= 1.0).then_some(p)
                    })
                })
            });
            (
                CellBox::new([-1.0; 3], [1.0; 3], depth * 2.4 * d, [false; 3]),
                Box::new(pts),
            )
        }
        _ => {
            let len = [1.0, 0.32, 0.27];
            let d = (len[0] * len[1] * len[2] / n).cbrt();
            let c = len.map(|l| (l / d).round().max(1.0) as i64);
            let pts = (0..c[0]).flat_map(move |i| {
                (0..c[1]).flat_map(move |j| {
                    (0..c[2]).map(move |k| {
                        [
                            (i as f64 + 0.5) * d,
                            (j as f64 + 0.5) * d,
                            (k as f64 + 0.5) * d,
                        ]
                    })
                })
            });
            (
                CellBox::new([0.0; 3], len, depth * 2.4 * d, [true; 3]),
                Box::new(pts),
            )
        }
    }
}

/// The model for `kind` ("ball" or "slab") at N particles over each rank count, with a halo
/// `depth` kernel supports deep.
pub fn model(
    kind: &str,
    n: f64,
    ranks: &[u32],
    bandwidth: f64,
    depth: f64,
    traffic: (f64, f64),
) -> (u64, Vec<Row>) {
    let (halo_bytes, exchanges) = traffic;
    let (cbox, pts) = cloud(kind, n, depth);
    let cells = Cells::bin(pts, cbox);
    let rows = ranks
        .iter()
        .map(|&r| {
            let p = Partition::of(&cells, r);
            let halo_max = *p.halo.iter().max().unwrap_or(&0);
            let peers_max = *p.peers.iter().max().unwrap_or(&0);
            Row {
                ranks: r,
                per_rank: cells.total as f64 / r as f64,
                imbalance: p.imbalance(),
                halo_max,
                halo_mean: p.halo.iter().sum::<u64>() as f64 / r as f64,
                peers_max,
                comm_s: halo_max as f64 * halo_bytes / bandwidth
                    + exchanges * peers_max as f64 * LATENCY_S,
            }
        })
        .collect();
    (cells.total, rows)
}

// ---------------------------------------------------------------------------------------------
// The command line.

#[derive(clap::Args)]
pub struct ScalingArgs {
    /// Particles per cloud
    #[arg(long, default_value_t = 1e8)]
    particles: f64,
    /// Rank counts
    #[arg(long, value_delimiter = ',', default_values_t = vec![1u32, 2, 4, 8, 16, 64, 256, 1024, 4096])]
    ranks: Vec<u32>,
    /// Interconnect bandwidth per rank, Gb/s
    #[arg(long, default_value_t = 200.0)]
    gbps: f64,
    /// Measured step throughput of one rank, particle-steps/s (default: this code's CPU bench,
    /// 3D box at 56 neighbours on 2 cores)
    #[arg(long, default_value_t = 1.95e6)]
    rate: f64,
    /// Halo depth in kernel supports: 1 for an exchange before each neighbour pass; the length
    /// of the step's chain of neighbour passes for one exchange per step (then halo/owned is
    /// also the redundant compute)
    #[arg(long, default_value_t = 1.0)]
    depth: f64,
    /// Bytes a ghost receives per step (default: measured over ranks, docs/scaling.md)
    #[arg(long, default_value_t = HALO_BYTES_F64)]
    halo_bytes: f64,
    /// Exchanges per step, each a message to every peer (default: measured)
    #[arg(long, default_value_t = EXCHANGES)]
    exchanges: f64,
}

pub fn execute(a: ScalingArgs) -> u8 {
    use crate::commands::scaling;
    if !(a.particles.is_finite() && a.particles >= 1.0 && a.particles <= 2e9) {
        eprintln!("error: --particles must be in [1, 2e9]");
        return 2;
    }
    if a.ranks.is_empty()
        || a.ranks.contains(&0)
        || !(a.gbps > 0.0 && a.rate > 0.0 && a.depth >= 1.0 && a.depth <= 64.0)
        || !(a.halo_bytes >= 0.0 && a.halo_bytes.is_finite())
        || !(a.exchanges >= 0.0 && a.exchanges.is_finite())
    {
        eprintln!(
            "error: --ranks must be ≥ 1, --gbps and --rate > 0, --depth in [1, 64], \
             --halo-bytes and --exchanges ≥ 0"
        );
        return 2;
    }
    let bw = a.gbps * 1e9 / 8.0;
    for kind in ["ball", "slab"] {
        let t0 = std::time::Instant::now();
        let traffic = (a.halo_bytes, a.exchanges);
        let (n, rows) = scaling::model(kind, a.particles, &a.ranks, bw, a.depth, traffic);
        println!(
            "\n{kind}: {n} particles, h = 1.2 Δ, halo {} × 2h deep ({:.1} s); {} B per halo particle, \
             {} exchanges per step, {} µs per message; compute at {:.3e} particle-steps/s per rank",
            a.depth,
            t0.elapsed().as_secs_f64(),
            a.halo_bytes,
            a.exchanges,
            scaling::LATENCY_S * 1e6,
            a.rate
        );
        println!(
            "| ranks | particles/rank | imbalance | halo max | halo/owned | peers max | MB/step | comm ms | compute ms | comm/compute | break-even particle-steps/s |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|");
        for r in rows {
            let compute = r.per_rank * r.imbalance / a.rate;
            println!(
                "| {} | {:.3e} | {:.3} | {:.3e} | {:.3} | {} | {:.2} | {:.3} | {:.1} | {:.4} | {} |",
                r.ranks,
                r.per_rank,
                r.imbalance,
                r.halo_max as f64,
                r.halo_max as f64 / r.per_rank,
                r.peers_max,
                r.halo_max as f64 * a.halo_bytes / 1e6,
                r.comm_s * 1e3,
                compute * 1e3,
                r.comm_s / compute,
                if r.comm_s > 0.0 {
                    format!("{:.2e}", r.per_rank * r.imbalance / r.comm_s)
                } else {
                    "–".into()
                }
            );
        }
    }
    0
}
