//! The MLP's shape (`MlpConfig`: widths, layers, activations, fp16 hidden activations) and its sizes: parameter
//! counts, padded widths, activation and scratch floats, multiply-adds per row.

use super::*;

#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    None,
    Sigmoid,
    /// exp forward; backward derivative exp(clamp(x, -15, 15)) (nerfstudio's trunc_exp).
    Exponential,
    Relu,
}

impl Activation {
    pub(super) fn code(self) -> u32 {
        match self {
            Self::None => 0,
            Self::Sigmoid => 1,
            Self::Exponential => 2,
            Self::Relu => 3,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MlpConfig {
    pub n_input: usize,
    pub n_output: usize,
    pub width: usize,
    pub n_hidden_layers: usize,
    pub output_activation: Activation,
    /// Hidden activations stored as fp16 (the products and sums stay fp32): halves the largest buffers of a
    /// training step and the memory traffic of the layers that read them. Inputs, outputs, deltas and gradients
    /// stay fp32. The ReLU mask of the backward pass and the weight gradients use the stored fp16 values.
    #[serde(default)]
    pub half_activations: bool,
}

impl MlpConfig {
    pub fn validate(&self) -> Result<(), SettingError> {
        if ![16, 32, 64, 128].contains(&self.width) {
            return Err(SettingError::new("width", format!("must be 16, 32, 64 or 128, got {}", self.width)));
        }
        if self.n_hidden_layers == 0 || self.n_hidden_layers > 8 {
            return Err(SettingError::new("n_hidden_layers", format!("must be 1..=8, got {}", self.n_hidden_layers)));
        }
        if self.n_input == 0 || self.n_input > 256 || self.n_output == 0 || self.n_output > 256 {
            return Err(SettingError::new(
                "n_input/n_output",
                format!("must be 1..=256, got {} and {}", self.n_input, self.n_output),
            ));
        }
        Ok(())
    }

    pub fn in_pad(&self) -> usize {
        self.n_input.next_multiple_of(16)
    }

    pub fn out_pad(&self) -> usize {
        self.n_output.next_multiple_of(16)
    }

    /// (rows, columns) of every matrix, first to last.
    pub fn matrices(&self) -> Vec<(usize, usize)> {
        let mut m = vec![(self.width, self.in_pad())];
        m.extend(std::iter::repeat_n((self.width, self.width), self.n_hidden_layers - 1));
        m.push((self.out_pad(), self.width));
        m
    }

    pub fn n_params(&self) -> usize {
        self.matrices().iter().map(|(r, c)| r * c).sum()
    }

    /// Hidden activation values of `n` rows (as many hidden deltas).
    pub fn hidden_values(&self, n: usize) -> usize {
        self.n_hidden_layers * n * self.width
    }

    /// Floats of storage for the hidden activations of `n` rows: one per value, or one per two when
    /// `half_activations` (laid out as half[N_HIDDEN][n][WIDTH], strides and columns counted in halves).
    pub fn hidden_floats(&self, n: usize) -> usize {
        if self.half_activations {
            self.hidden_values(n).div_ceil(2)
        } else {
            self.hidden_values(n)
        }
    }

    /// Floats of the deltas buffer for `n` rows: hidden deltas, then output deltas (always fp32).
    pub fn delta_floats(&self, n: usize) -> usize {
        self.hidden_values(n) + n * self.out_delta_cols()
    }

    /// Columns (and row stride) of the output deltas: n_output rounded up to 4, the widest the kernels that read
    /// them need (zeros past n_output); not `out_pad`, which for one density output would store 16.
    pub fn out_delta_cols(&self) -> usize {
        self.n_output.next_multiple_of(4).min(self.out_pad())
    }

    /// Floats of the split-K scratch of the weight gradients for `n` rows.
    pub fn wgrad_scratch_floats(&self, n: usize) -> usize {
        let splits = n.div_ceil(ROWS_PER_SPLIT).max(1);
        splits * self.matrices().iter().map(|(r, c)| r * c).max().unwrap_or(0)
    }

    /// Floats of the hidden-layer scratch that inference over `n` rows needs (it runs in blocks of
    /// [`INFER_BLOCK_ROWS`] rows; a training activations buffer for as many rows is large enough too).
    pub fn infer_scratch_floats(&self, n: usize) -> usize {
        self.hidden_floats(n.min(INFER_BLOCK_ROWS))
    }

    /// (outputs, inputs) of every layer as computed: the matrices, with the last one's padding rows left out.
    pub fn layer_shapes(&self) -> Vec<(usize, usize)> {
        let mut m = self.matrices();
        if let Some(last) = m.last_mut() {
            last.0 = self.n_output;
        }
        m
    }

    /// Multiply-adds per row of a forward pass (x2 for FLOPs; the backward costs twice the forward).
    pub fn macs_per_row(&self) -> usize {
        self.layer_shapes().iter().map(|(r, c)| r * c).sum()
    }
}
