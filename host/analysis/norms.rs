//! Mass-weighted particle norms (method.md §8).
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct Norms {
    pub l1: f64,
    pub l2: f64,
    pub linf: f64,
}

impl Norms {
    /// L1 = Σ m|e|/Σ m, L2 = sqrt(Σ m e²/Σ m), L∞ = max|e|.
    pub fn of(err: &[f64], m: &[f64]) -> Norms {
        Norms::over(&crate::dist::Alone, err, m)
    }

    /// [`Norms::of`] of the particles every process of `c` holds a share of (`err`, `m`: this
    /// process's; collective): the sums and the largest error over the processes.
    pub fn over(c: &dyn crate::dist::Comm, err: &[f64], m: &[f64]) -> Norms {
        let mut s = [
            m.iter().sum::<f64>(),
            err.iter().zip(m).map(|(e, m)| m * e.abs()).sum::<f64>(),
            err.iter().zip(m).map(|(e, m)| m * e * e).sum::<f64>(),
            err.len() as f64,
        ];
        c.sum_f64(&mut s);
        let mut linf = [err.iter().fold(0.0f64, |a, e| a.max(e.abs()))];
        c.max_f64(&mut linf);
        let [mt, l1, l2, n] = s;
        if n == 0.0 || mt <= 0.0 {
            return Norms {
                l1: 0.0,
                l2: 0.0,
                linf: 0.0,
            };
        }
        Norms {
            l1: l1 / mt,
            l2: (l2 / mt).sqrt(),
            linf: linf[0],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weighted_norms() {
        let n = Norms::of(&[1.0, -3.0], &[3.0, 1.0]);
        assert!((n.l1 - 1.5).abs() < 1e-15);
        assert!((n.l2 - 3.0f64.sqrt()).abs() < 1e-15);
        assert_eq!(n.linf, 3.0);
    }
}
