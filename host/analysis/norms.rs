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
        let mt: f64 = m.iter().sum();
        if err.is_empty() || mt <= 0.0 {
            return Norms {
                l1: 0.0,
                l2: 0.0,
                linf: 0.0,
            };
        }
        let l1 = err.iter().zip(m).map(|(e, m)| m * e.abs()).sum::<f64>() / mt;
        let l2 = (err.iter().zip(m).map(|(e, m)| m * e * e).sum::<f64>() / mt).sqrt();
        let linf = err.iter().fold(0.0f64, |a, e| a.max(e.abs()));
        Norms { l1, l2, linf }
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
