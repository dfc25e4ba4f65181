//! Flat `f32` parameter layout of a tanh MLP, the wire format of policy weights.
//!
//! Layer `l` maps `sizes[l]` inputs to `sizes[l + 1]` outputs. Its weight matrix is stored
//! row-major as `[out][in]` (the layout of `torch.nn.Linear.weight`), followed by its bias
//! `[out]`; layers follow each other. Hidden layers use `tanh`, the last is linear.

use thiserror::Error;

/// Errors about a weights buffer that does not fit its layout.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum WeightsError {
    /// The buffer holds a different number of floats than the layout needs.
    #[error("weights buffer holds {got} floats, layout {sizes:?} needs {expected}")]
    Length {
        /// Layer sizes of the layout.
        sizes: Vec<usize>,
        /// Floats the layout needs.
        expected: usize,
        /// Floats the buffer holds.
        got: usize,
    },
    /// A layout needs at least an input and an output size, none of them zero.
    #[error("invalid MLP layout {sizes:?}: needs >= 2 sizes, all > 0")]
    Layout {
        /// The offending sizes.
        sizes: Vec<usize>,
    },
}

/// Shape of a tanh MLP: `sizes = [in, hidden.., out]`.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct MlpLayout {
    /// Layer widths, input first, output last.
    pub sizes: Vec<usize>,
}

impl MlpLayout {
    /// A layout `[input, hidden..., output]`, checked.
    pub fn new(input: usize, hidden: &[usize], output: usize) -> Result<Self, WeightsError> {
        let mut sizes = Vec::with_capacity(hidden.len() + 2);
        sizes.push(input);
        sizes.extend_from_slice(hidden);
        sizes.push(output);
        if sizes.contains(&0) {
            return Err(WeightsError::Layout { sizes });
        }
        Ok(Self { sizes })
    }

    /// Number of linear layers.
    pub fn n_layers(&self) -> usize {
        self.sizes.len() - 1
    }

    /// Input width.
    pub fn input(&self) -> usize {
        self.sizes[0]
    }

    /// Output width.
    pub fn output(&self) -> usize {
        self.sizes[self.sizes.len() - 1]
    }

    /// Widest layer, the scratch size a forward pass needs.
    pub fn max_width(&self) -> usize {
        self.sizes.iter().copied().max().unwrap_or(0)
    }

    /// Total number of floats.
    pub fn n_params(&self) -> usize {
        self.sizes.windows(2).map(|w| w[0] * w[1] + w[1]).sum()
    }

    /// `(weight_offset, bias_offset)` of layer `l` in the flat buffer.
    pub fn offsets(&self, l: usize) -> (usize, usize) {
        let before: usize = self.sizes[..=l]
            .windows(2)
            .map(|w| w[0] * w[1] + w[1])
            .sum();
        (before, before + self.sizes[l] * self.sizes[l + 1])
    }

    /// Checks that `buf` has exactly the floats this layout needs.
    pub fn check(&self, buf: &[f32]) -> Result<(), WeightsError> {
        if self.sizes.len() < 2 || self.sizes.contains(&0) {
            return Err(WeightsError::Layout {
                sizes: self.sizes.clone(),
            });
        }
        if buf.len() != self.n_params() {
            return Err(WeightsError::Length {
                sizes: self.sizes.clone(),
                expected: self.n_params(),
                got: buf.len(),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_follow_weight_then_bias_per_layer() {
        let l = MlpLayout::new(3, &[4], 2).unwrap();
        assert_eq!(l.n_params(), 3 * 4 + 4 + 4 * 2 + 2);
        assert_eq!(l.offsets(0), (0, 12));
        assert_eq!(l.offsets(1), (16, 24));
        assert!(l.check(&[0.0; 26]).is_ok());
        assert_eq!(
            l.check(&[0.0; 25]),
            Err(WeightsError::Length {
                sizes: vec![3, 4, 2],
                expected: 26,
                got: 25
            })
        );
    }

    #[test]
    fn zero_width_layout_is_rejected() {
        assert!(MlpLayout::new(0, &[4], 2).is_err());
    }
}
