//! Continuous box spaces, the only kind the walkers and the learners need.

use serde::{Deserialize, Serialize};

/// A box in R^n: each component lies in `[low[i], high[i]]` (bounds may be infinite).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoxSpace {
    /// Lower bound per component.
    pub low: Vec<f32>,
    /// Upper bound per component.
    pub high: Vec<f32>,
}

impl BoxSpace {
    /// A box with the given bounds; panics if their lengths differ or `low > high` somewhere,
    /// since spaces are built by environment code, never from user input.
    pub fn new(low: Vec<f32>, high: Vec<f32>) -> Self {
        assert_eq!(low.len(), high.len(), "space bounds of different lengths");
        assert!(
            low.iter().zip(&high).all(|(l, h)| l <= h),
            "space with low > high"
        );
        Self { low, high }
    }

    /// The box `[lo, hi]^n`.
    pub fn uniform(n: usize, lo: f32, hi: f32) -> Self {
        Self::new(vec![lo; n], vec![hi; n])
    }

    /// Number of components.
    pub fn dim(&self) -> usize {
        self.low.len()
    }

    /// Whether `x` has the right length and lies inside the box.
    pub fn contains(&self, x: &[f32]) -> bool {
        x.len() == self.dim()
            && x.iter()
                .zip(self.low.iter().zip(&self.high))
                .all(|(v, (l, h))| *v >= *l && *v <= *h)
    }

    /// Clamps every component of `x` into the box in place.
    pub fn clip(&self, x: &mut [f32]) {
        for (v, (l, h)) in x.iter_mut().zip(self.low.iter().zip(&self.high)) {
            *v = v.clamp(*l, *h);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contains_and_clip() {
        let s = BoxSpace::uniform(2, -1.0, 1.0);
        assert!(s.contains(&[0.5, -1.0]));
        assert!(!s.contains(&[1.5, 0.0]));
        assert!(!s.contains(&[0.0]));
        let mut x = [3.0, -2.0];
        s.clip(&mut x);
        assert_eq!(x, [1.0, -1.0]);
    }
}
