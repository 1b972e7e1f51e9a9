//! The nerfacto model for B bands: the NeRF field (hash grid, density MLP, colour MLP with B sigmoid outputs,
//! optional appearance embeddings) and the proposal density fields, with their parameters in one store
//! (groups `fields` and `proposals`, nerfacto's optimiser split). Built from a [`ModelConfig`].

use super::config::ModelConfig;
use crate::gpu::{Context, GpuResult};
use crate::nn::hashgrid::{HashGrid, OutputSlot};
use crate::nn::mlp::{Activation, Mlp, MlpConfig};
use crate::nn::params::{MatrixShape, ParamError, ParamGroup, ParamStore, ParamStoreDesc, SlotDesc, SlotKind};

/// Widths of one density field (a proposal or the NeRF density part).
pub struct DensityField {
    pub grid: HashGrid,
    pub mlp: Mlp,
    pub grid_slot: String,
    pub mlp_slot: String,
    /// Where the encoding lands in the MLP input rows (stride = MLP in_pad).
    pub enc_slot: OutputSlot,
}

pub struct Model {
    pub cfg: ModelConfig,
    pub bands: usize,
    pub n_cameras: usize,
    pub proposals: Vec<DensityField>,
    pub field: DensityField,
    pub colour: Mlp,
    pub store: ParamStore,
}

fn mlp_shapes(c: &MlpConfig) -> Vec<MatrixShape> {
    c.matrices().into_iter().map(|(rows, cols)| MatrixShape { fan_in: cols, fan_out: rows }).collect()
}

impl Model {
    /// Colour MLP input width before padding: SH 16 + geometric features + appearance.
    pub fn colour_inputs(cfg: &ModelConfig) -> usize {
        16 + cfg.field.geo_feat_dim + cfg.field.appearance_embed_dim
    }

    pub fn new(ctx: &Context, cfg: &ModelConfig, bands: usize, n_cameras: usize) -> Result<Self, ParamError> {
        let f = &cfg.field;
        let gpu = |e: crate::gpu::GpuError| ParamError::Gpu(e);
        let density_field =
            |ctx: &Context, grid: &crate::nn::hashgrid::HashGridConfig, width, layers, n_out, pad, name: &str| {
                let enc = grid.n_output();
                let mlp_cfg = MlpConfig {
                    n_input: enc,
                    n_output: n_out,
                    width,
                    n_hidden_layers: layers - 1,
                    output_activation: Activation::None,
                };
                let grid_k = HashGrid::new(ctx, grid)?;
                let mlp = Mlp::new(ctx, &mlp_cfg)?;
                let in_pad = mlp_cfg.in_pad();
                GpuResult::Ok(DensityField {
                    grid: grid_k,
                    mlp,
                    grid_slot: format!("{name}.grid"),
                    mlp_slot: format!("{name}.mlp"),
                    enc_slot: OutputSlot { stride: in_pad, col: 0, pad_to: in_pad, pad_value: pad },
                })
            };
        // tcnn pads the proposal MLPs' inputs with ones (a learned bias); the field's grid output (32) needs none.
        let proposals = cfg
            .proposals
            .iter()
            .enumerate()
            .map(|(i, p)| density_field(ctx, &p.grid, p.hidden_dim, p.num_layers, 1, 1.0, &format!("proposal{i}")))
            .collect::<GpuResult<Vec<_>>>()
            .map_err(gpu)?;
        let field =
            density_field(ctx, &f.grid, f.hidden_dim, f.num_layers, 1 + f.geo_feat_dim, 0.0, "field").map_err(gpu)?;
        let colour_cfg = MlpConfig {
            n_input: Self::colour_inputs(cfg),
            n_output: bands,
            width: f.hidden_dim_color,
            n_hidden_layers: f.num_layers_color - 1,
            output_activation: Activation::Sigmoid,
        };
        let colour = Mlp::new(ctx, &colour_cfg).map_err(gpu)?;

        let o = &cfg.optimizer;
        let groups = vec![
            ParamGroup::new("fields", o.fields.lr, o.fields.lr_final, o.fields.max_steps),
            ParamGroup::new("proposals", o.proposals.lr, o.proposals.lr_final, o.proposals.max_steps),
        ]
        .into_iter()
        .zip([o.fields.eps, o.proposals.eps])
        .map(|(mut g, eps)| {
            g.adam.eps = eps;
            g
        })
        .collect::<Vec<_>>();
        let mut slots = vec![
            SlotDesc::new(&field.grid_slot, SlotKind::HashTable { len: f.grid.n_params() }, "fields"),
            SlotDesc::new(&field.mlp_slot, SlotKind::Mlp { matrices: mlp_shapes(&field.mlp.config) }, "fields"),
            SlotDesc::new("field.colour_mlp", SlotKind::Mlp { matrices: mlp_shapes(&colour_cfg) }, "fields"),
        ];
        if f.appearance_embed_dim > 0 {
            slots.push(SlotDesc::new(
                "field.appearance",
                // One row per camera plus a spare row that holds the mean embedding for evaluation.
                SlotKind::Embedding { rows: n_cameras + 1, dim: f.appearance_embed_dim },
                "fields",
            ));
        }
        for (p, pc) in proposals.iter().zip(&cfg.proposals) {
            slots.push(SlotDesc::new(&p.grid_slot, SlotKind::HashTable { len: pc.grid.n_params() }, "proposals"));
            slots.push(SlotDesc::new(&p.mlp_slot, SlotKind::Mlp { matrices: mlp_shapes(&p.mlp.config) }, "proposals"));
        }
        let store = ParamStore::new(
            ctx,
            &ParamStoreDesc { name: &cfg.name, groups, slots, seed: cfg.trainer.seed, chunk_shift: None },
        )?;
        Ok(Self { cfg: cfg.clone(), bands, n_cameras, proposals, field, colour, store })
    }

    /// Offset of a slot in the store's arrays.
    pub fn offset(&self, slot: &str) -> usize {
        self.store.slot(slot).map(|s| s.offset).expect("slots are created with the model")
    }

    pub fn n_params(&self) -> usize {
        self.store.slots().iter().map(|s| s.len).sum()
    }
}
