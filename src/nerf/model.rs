//! The nerfacto model for B bands: the NeRF field (hash grid, density MLP, colour MLP with B sigmoid outputs,
//! optional appearance embeddings) and the proposal density fields, with their parameters in one store
//! (groups `fields` and `proposals`, nerfacto's optimiser split). Built from a [`ModelConfig`].

use super::config::{ActivationStorage, ModelConfig};
use crate::gpu::{Context, GpuResult};
use crate::nn::hashgrid::{HashGrid, HashGridConfig, OutputSlot};
use crate::nn::mlp::{Activation, Mlp, MlpConfig};
use crate::nn::params::{MatrixShape, ParamError, ParamGroup, ParamStore, ParamStoreDesc, SlotDesc, SlotKind};

/// The parameter slot of the camera pose corrections (6 floats per camera) and its optimiser group.
pub const POSE_SLOT: &str = "camera.pose";
pub const CAMERA_GROUP: &str = "camera";

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

/// What the model's GPU buffers depend on, from the configuration alone (no device): the MLP shapes, the parameter
/// groups and slots, and the hash grids. [`Model::new`] builds from it and the VRAM planner (`crate::plan`) plans
/// from it, so the two cannot disagree.
#[derive(Clone, Debug)]
pub struct ModelShapes {
    pub cfg: ModelConfig,
    pub bands: usize,
    pub n_cameras: usize,
    /// Density MLP of each proposal level, coarse to fine.
    pub proposal_mlps: Vec<MlpConfig>,
    pub field_mlp: MlpConfig,
    pub colour_mlp: MlpConfig,
}

fn density_mlp(grid: &HashGridConfig, width: usize, layers: usize, n_out: usize, half: bool) -> MlpConfig {
    MlpConfig {
        n_input: grid.n_output(),
        n_output: n_out,
        width,
        n_hidden_layers: layers - 1,
        output_activation: Activation::None,
        half_activations: half,
    }
}

impl ModelShapes {
    pub fn new(cfg: &ModelConfig, bands: usize, n_cameras: usize) -> Self {
        let f = &cfg.field;
        let half = cfg.mlp_activations == ActivationStorage::F16;
        Self {
            cfg: cfg.clone(),
            bands,
            n_cameras,
            proposal_mlps: cfg
                .proposals
                .iter()
                .map(|p| density_mlp(&p.grid, p.hidden_dim, p.num_layers, 1, half))
                .collect(),
            field_mlp: density_mlp(&f.grid, f.hidden_dim, f.num_layers, 1 + f.geo_feat_dim, half),
            colour_mlp: MlpConfig {
                n_input: Model::colour_inputs(cfg),
                n_output: bands,
                width: f.hidden_dim_color,
                n_hidden_layers: f.num_layers_color - 1,
                output_activation: Activation::Sigmoid,
                half_activations: half,
            },
        }
    }

    /// Every hash grid of the model (the field's first, then the proposals'), each with one level-table buffer.
    pub fn grids(&self) -> Vec<&HashGridConfig> {
        std::iter::once(&self.cfg.field.grid).chain(self.cfg.proposals.iter().map(|p| &p.grid)).collect()
    }

    /// The optimiser groups (`fields`, `proposals`, and `camera` when poses are refined) with the configured schedules.
    pub fn param_groups(&self) -> Vec<ParamGroup> {
        let o = &self.cfg.optimizer;
        let co = &self.cfg.camera_optimizer;
        let mut groups = vec![
            (ParamGroup::new("fields", o.fields.lr, o.fields.lr_final, o.fields.max_steps), o.fields.eps),
            (
                ParamGroup::new("proposals", o.proposals.lr, o.proposals.lr_final, o.proposals.max_steps),
                o.proposals.eps,
            ),
        ];
        if co.enabled() {
            groups.push((ParamGroup::new(CAMERA_GROUP, co.lr, co.lr_final, co.max_steps), co.eps));
        }
        groups
            .into_iter()
            .map(|(mut g, eps)| {
                g.adam.eps = eps;
                g
            })
            .collect()
    }

    /// The parameter store's slots, in store order.
    pub fn param_slots(&self) -> Vec<SlotDesc> {
        let f = &self.cfg.field;
        let mut slots = vec![
            SlotDesc::new("field.grid", SlotKind::HashTable { len: f.grid.n_params() }, "fields"),
            SlotDesc::new("field.mlp", SlotKind::Mlp { matrices: mlp_shapes(&self.field_mlp) }, "fields"),
            SlotDesc::new("field.colour_mlp", SlotKind::Mlp { matrices: mlp_shapes(&self.colour_mlp) }, "fields"),
        ];
        if f.appearance_embed_dim > 0 {
            slots.push(SlotDesc::new(
                "field.appearance",
                // One row per camera plus a spare row that holds the mean embedding for evaluation.
                SlotKind::Embedding { rows: self.n_cameras + 1, dim: f.appearance_embed_dim },
                "fields",
            ));
        }
        if self.cfg.camera_optimizer.enabled() {
            // [t(3), w(3)] per camera, zero = the poses as given.
            slots.push(SlotDesc::new(POSE_SLOT, SlotKind::Zeros { len: 6 * self.n_cameras }, CAMERA_GROUP));
        }
        for (i, (pc, m)) in self.cfg.proposals.iter().zip(&self.proposal_mlps).enumerate() {
            slots.push(SlotDesc::new(
                &format!("proposal{i}.grid"),
                SlotKind::HashTable { len: pc.grid.n_params() },
                "proposals",
            ));
            slots.push(SlotDesc::new(
                &format!("proposal{i}.mlp"),
                SlotKind::Mlp { matrices: mlp_shapes(m) },
                "proposals",
            ));
        }
        slots
    }

    /// The store's creation parameters (`chunk_shift` None: as large as one binding of the device allows).
    pub fn store_desc(&self, chunk_shift: Option<u32>) -> ParamStoreDesc<'_> {
        ParamStoreDesc {
            name: &self.cfg.name,
            groups: self.param_groups(),
            slots: self.param_slots(),
            seed: self.cfg.trainer.seed,
            chunk_shift,
        }
    }
}

impl Model {
    /// Colour MLP input width before padding: SH (degree 4, [`SH_DIM`](crate::nn::sh::SH_DIM) = 16) + geometric
    /// features + appearance.
    pub fn colour_inputs(cfg: &ModelConfig) -> usize {
        crate::nn::sh::SH_DIM + cfg.field.geo_feat_dim + cfg.field.appearance_embed_dim
    }

    pub fn new(ctx: &Context, cfg: &ModelConfig, bands: usize, n_cameras: usize) -> Result<Self, ParamError> {
        let shapes = ModelShapes::new(cfg, bands, n_cameras);
        let gpu = |e: crate::gpu::GpuError| ParamError::Gpu(e);
        let density_field = |ctx: &Context, grid: &HashGridConfig, mlp_cfg: &MlpConfig, pad, name: &str| {
            let grid_k = HashGrid::new(ctx, grid)?;
            let mlp = Mlp::new(ctx, mlp_cfg)?;
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
            .zip(&shapes.proposal_mlps)
            .enumerate()
            .map(|(i, (p, m))| density_field(ctx, &p.grid, m, 1.0, &format!("proposal{i}")))
            .collect::<GpuResult<Vec<_>>>()
            .map_err(gpu)?;
        let field = density_field(ctx, &cfg.field.grid, &shapes.field_mlp, 0.0, "field").map_err(gpu)?;
        let colour = Mlp::new(ctx, &shapes.colour_mlp).map_err(gpu)?;
        let store = ParamStore::new(ctx, &shapes.store_desc(None))?;
        Ok(Self { cfg: cfg.clone(), bands, n_cameras, proposals, field, colour, store })
    }

    /// The configuration-only description this model was built from.
    pub fn shapes(&self) -> ModelShapes {
        ModelShapes::new(&self.cfg, self.bands, self.n_cameras)
    }

    /// Offset of a slot in the store's arrays.
    pub fn offset(&self, slot: &str) -> usize {
        self.store.slot(slot).map(|s| s.offset).expect("slots are created with the model")
    }

    pub fn n_params(&self) -> usize {
        self.store.slots().iter().map(|s| s.len).sum()
    }
}
