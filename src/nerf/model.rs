//! The nerfacto model for B bands: the NeRF field (hash grid, density MLP, colour MLP with B sigmoid outputs,
//! optional appearance embeddings) and the proposal density fields, with their parameters in one store
//! (groups `fields` and `proposals`, nerfacto's optimiser split). Built from a [`ModelConfig`].

use super::config::{ActivationStorage, ModelConfig};
use crate::gpu::{Context, GpuResult};
use crate::nn::hashgrid::{HashGrid, HashGridConfig, OutputSlot};
use crate::nn::mlp::{Activation, Mlp, MlpConfig};
use crate::nn::params::{
    MatrixShape, ParamError, ParamGroup, ParamSlot, ParamStore, ParamStoreDesc, SlotDesc, SlotKind,
};

/// The parameter slot of the camera pose corrections (6 floats per camera) and its optimiser group.
pub const POSE_SLOT: &str = "camera.pose";
pub const CAMERA_GROUP: &str = "camera";
/// The optimiser group of the NeRF field's grid and MLPs (`metrics.jsonl` logs its learning rate as `lr_fields`).
pub const FIELDS_GROUP: &str = "fields";
/// The NeRF field's density part ([`density_slots`] gives its grid and MLP slots).
pub const FIELD: &str = "field";
/// The colour MLP's slot.
pub const COLOUR_MLP_SLOT: &str = "field.colour_mlp";
/// The appearance embeddings' slot (one row per camera plus the evaluation row).
pub const APPEARANCE_SLOT: &str = "field.appearance";

/// The proposal network `i`'s name ([`density_slots`] gives its slots).
pub fn proposal_name(i: usize) -> String {
    format!("proposal{i}")
}

/// The (hash grid, MLP) slot names of density field `name` ([`FIELD`] or a [`proposal_name`]).
pub fn density_slots(name: &str) -> (String, String) {
    (format!("{name}.grid"), format!("{name}.mlp"))
}

/// The slots the pipeline reads every step, resolved once when the model is built (no lookup by name per call).
#[derive(Clone, Debug)]
pub struct ModelSlots {
    pub colour_mlp: ParamSlot,
    pub appearance: Option<ParamSlot>,
    pub pose: Option<ParamSlot>,
}

/// Widths of one density field (a proposal or the NeRF density part).
pub struct DensityField {
    pub grid: HashGrid,
    pub mlp: Mlp,
    /// Offsets of the hash table and the MLP weights in the store's arrays.
    pub grid_offset: usize,
    pub mlp_offset: usize,
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
    pub slots: ModelSlots,
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
    /// Rows of the camera table: `n_cameras`, or with `rig_cameras` every frame's band cameras too (1 + B per frame).
    pub table_cameras: usize,
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
            table_cameras: n_cameras,
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
            (ParamGroup::new(FIELDS_GROUP, o.fields.lr, o.fields.lr_final, o.fields.max_steps), o.fields.eps),
            (
                ParamGroup::new("proposals", o.proposals.lr, o.proposals.lr_final, o.proposals.max_steps),
                o.proposals.eps,
            ),
        ];
        for (g, _) in &mut groups {
            g.over_run = o.schedule == super::config::LrSchedule::Run;
        }
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
        let (grid, mlp) = density_slots(FIELD);
        let mut slots = vec![
            SlotDesc::new(&grid, SlotKind::HashTable { len: f.grid.n_params() }, FIELDS_GROUP),
            SlotDesc::new(&mlp, SlotKind::Mlp { matrices: mlp_shapes(&self.field_mlp) }, FIELDS_GROUP),
            SlotDesc::new(COLOUR_MLP_SLOT, SlotKind::Mlp { matrices: mlp_shapes(&self.colour_mlp) }, FIELDS_GROUP),
        ];
        if f.appearance_embed_dim > 0 {
            slots.push(SlotDesc::new(
                APPEARANCE_SLOT,
                // One row per camera plus a spare row that holds the mean embedding for evaluation.
                SlotKind::Embedding { rows: self.n_cameras + 1, dim: f.appearance_embed_dim },
                FIELDS_GROUP,
            ));
        }
        if self.cfg.camera_optimizer.enabled() {
            // [t(3), w(3)] per camera, zero = the poses as given.
            slots.push(SlotDesc::new(POSE_SLOT, SlotKind::Zeros { len: 6 * self.n_cameras }, CAMERA_GROUP));
        }
        for (i, (pc, m)) in self.cfg.proposals.iter().zip(&self.proposal_mlps).enumerate() {
            let (grid, mlp) = density_slots(&proposal_name(i));
            slots.push(SlotDesc::new(&grid, SlotKind::HashTable { len: pc.grid.n_params() }, "proposals"));
            slots.push(SlotDesc::new(&mlp, SlotKind::Mlp { matrices: mlp_shapes(m) }, "proposals"));
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
    /// Sets every hash grid's limit for one dispatch for all levels ([`HashGrid::set_one_dispatch_max_points`]).
    pub fn set_hash_one_dispatch_max(&mut self, max: usize) {
        for f in std::iter::once(&mut self.field).chain(self.proposals.iter_mut()) {
            f.grid.set_one_dispatch_max_points(max);
        }
    }

    /// Colour MLP input width before padding: SH (degree 4, [`SH_DIM`](crate::nn::sh::SH_DIM) = 16) + geometric
    /// features + appearance.
    pub fn colour_inputs(cfg: &ModelConfig) -> usize {
        crate::nn::sh::SH_DIM + cfg.field.geo_feat_dim + cfg.field.appearance_embed_dim
    }

    pub fn new(ctx: &Context, cfg: &ModelConfig, bands: usize, n_cameras: usize) -> Result<Self, ParamError> {
        let shapes = ModelShapes::new(cfg, bands, n_cameras);
        let gpu = |e: crate::gpu::GpuError| ParamError::Gpu(e);
        // Offsets are filled in once the store exists (below).
        let density_field = |ctx: &Context, grid: &HashGridConfig, mlp_cfg: &MlpConfig, pad| {
            let grid_k = HashGrid::new(ctx, grid)?;
            let mlp = Mlp::new(ctx, mlp_cfg)?;
            let in_pad = mlp_cfg.in_pad();
            GpuResult::Ok(DensityField {
                grid: grid_k,
                mlp,
                grid_offset: 0,
                mlp_offset: 0,
                enc_slot: OutputSlot { stride: in_pad, col: 0, pad_to: in_pad, pad_value: pad },
            })
        };
        // tcnn pads the proposal MLPs' inputs with ones (a learned bias); the field's grid output (32) needs none.
        let mut proposals = cfg
            .proposals
            .iter()
            .zip(&shapes.proposal_mlps)
            .map(|(p, m)| density_field(ctx, &p.grid, m, 1.0))
            .collect::<GpuResult<Vec<_>>>()
            .map_err(gpu)?;
        let mut field = density_field(ctx, &cfg.field.grid, &shapes.field_mlp, 0.0).map_err(gpu)?;
        let colour = Mlp::new(ctx, &shapes.colour_mlp).map_err(gpu)?;
        let store = ParamStore::new(ctx, &shapes.store_desc(None))?;
        let slot = |name: &str| store.slot(name).cloned().expect("the store holds every slot the model declares");
        let names = std::iter::once(FIELD.to_owned()).chain((0..proposals.len()).map(proposal_name));
        for (f, name) in std::iter::once(&mut field).chain(proposals.iter_mut()).zip(names) {
            let (grid, mlp) = density_slots(&name);
            (f.grid_offset, f.mlp_offset) = (slot(&grid).offset, slot(&mlp).offset);
        }
        let slots = ModelSlots {
            colour_mlp: slot(COLOUR_MLP_SLOT),
            appearance: store.slot(APPEARANCE_SLOT).cloned(),
            pose: store.slot(POSE_SLOT).cloned(),
        };
        Ok(Self { cfg: cfg.clone(), bands, n_cameras, proposals, field, colour, store, slots })
    }

    /// The configuration-only description this model was built from.
    pub fn shapes(&self) -> ModelShapes {
        ModelShapes::new(&self.cfg, self.bands, self.n_cameras)
    }

    pub fn n_params(&self) -> usize {
        self.store.slots().iter().map(|s| s.len).sum()
    }
}
