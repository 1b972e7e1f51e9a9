//! Minimal SPIR-V reflection (kajiya reads layouts from SPIR-V too): the storage-buffer bindings a kernel
//! declares, its workgroup size (literal `LocalSize`, or the `WorkgroupSize` built-in made of specialisation
//! constants, resolved with the values the pipeline sets), its push-constant block (size, and each member's name,
//! byte offset and scalar type), its specialisation constants (SpecId, name, default value) and its shared memory.
//! `Kernel::new` checks these against the Rust side so a mismatch fails at creation, not as garbage output.
//!
//! Names come from `OpName` / `OpMemberName`: build.rs compiles with debug info (shaderc drops every debug
//! instruction when it optimises without) and strips only the line and source instructions.

use std::collections::HashMap;

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShaderInfo {
    /// Sorted binding numbers (descriptor set 0) of storage and uniform buffers.
    pub bindings: Vec<u32>,
    /// Sorted binding numbers of texel buffers and other `UniformConstant` resources.
    pub texel_bindings: Vec<u32>,
    pub local_size: [u32; 3],
    pub push_constant_bytes: u32,
    /// The push-constant block's members in declaration order (empty without a block).
    pub push_members: Vec<PushMember>,
    /// The specialisation constants (those decorated with a SpecId), sorted by SpecId.
    pub spec_constants: Vec<SpecConstant>,
    pub shared_bytes: u32,
}

/// The component type of a scalar, vector, matrix or array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScalarKind {
    Uint,
    Int,
    Float,
    Bool,
}

/// A scalar type: its kind and width in bytes (`bool` counts 4, as in a push block).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Scalar {
    pub kind: ScalarKind,
    pub bytes: u32,
}

impl std::fmt::Display for Scalar {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let k = match self.kind {
            ScalarKind::Uint => "u",
            ScalarKind::Int => "i",
            ScalarKind::Float => "f",
            ScalarKind::Bool => "bool",
        };
        write!(f, "{k}{}", 8 * self.bytes)
    }
}

/// One member of the push-constant block.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PushMember {
    /// `OpMemberName` (empty if the SPIR-V carries no names).
    pub name: String,
    /// Byte offset (`Offset` decoration).
    pub offset: u32,
    /// Byte size (a vector's or array's whole extent).
    pub size: u32,
    /// Component type; None for a struct or pointer member.
    pub scalar: Option<Scalar>,
}

/// A specialisation constant: `layout(constant_id = id) const uint NAME = default;`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SpecConstant {
    pub id: u32,
    /// `OpName` of the constant (empty if the SPIR-V carries no names).
    pub name: String,
    /// The shader's default (first word; `true` is 1).
    pub default: u32,
}

const OP_NAME: u16 = 5;
const OP_MEMBER_NAME: u16 = 6;
const OP_EXECUTION_MODE: u16 = 16;
const OP_TYPE_BOOL: u16 = 20;
const OP_TYPE_INT: u16 = 21;
const OP_TYPE_FLOAT: u16 = 22;
const OP_TYPE_VECTOR: u16 = 23;
const OP_TYPE_MATRIX: u16 = 24;
const OP_TYPE_ARRAY: u16 = 28;
const OP_TYPE_STRUCT: u16 = 30;
const OP_TYPE_POINTER: u16 = 32;
const OP_CONSTANT: u16 = 43;
const OP_CONSTANT_COMPOSITE: u16 = 44;
const OP_SPEC_CONSTANT_TRUE: u16 = 48;
const OP_SPEC_CONSTANT_FALSE: u16 = 49;
const OP_SPEC_CONSTANT: u16 = 50;
const OP_SPEC_CONSTANT_COMPOSITE: u16 = 51;
const OP_VARIABLE: u16 = 59;
const OP_DECORATE: u16 = 71;
const OP_MEMBER_DECORATE: u16 = 72;

const DEC_SPEC_ID: u32 = 1;
const DEC_ARRAY_STRIDE: u32 = 6;
const DEC_BUILTIN: u32 = 11;
const DEC_BINDING: u32 = 33;
const DEC_OFFSET: u32 = 35;
const BUILTIN_WORKGROUP_SIZE: u32 = 25;
const MODE_LOCAL_SIZE: u32 = 17;
const SC_UNIFORM_CONSTANT: u32 = 0;
const SC_UNIFORM: u32 = 2;
const SC_WORKGROUP: u32 = 4;
const SC_PUSH_CONSTANT: u32 = 9;
const SC_STORAGE_BUFFER: u32 = 12;

#[derive(Clone, Debug)]
enum Ty {
    Scalar(Scalar),
    Vector(u32, u32),
    Array(u32, u32),
    Struct(Vec<u32>),
    Pointer(u32),
}

/// Reflects `words` with the given specialisation constant values (id -> value) applied.
pub fn reflect(words: &[u32], spec: &[(u32, u32)]) -> Result<ShaderInfo, String> {
    if words.len() < 5 || words[0] != 0x0723_0203 {
        return Err("not SPIR-V (bad magic number)".into());
    }
    let mut types: HashMap<u32, Ty> = HashMap::new();
    let mut constants: HashMap<u32, u32> = HashMap::new();
    let mut spec_const_ids: HashMap<u32, u32> = HashMap::new(); // result id -> SpecId
    let mut composites: HashMap<u32, Vec<u32>> = HashMap::new();
    let mut bindings: HashMap<u32, u32> = HashMap::new();
    let mut strides: HashMap<u32, u32> = HashMap::new();
    let mut offsets: HashMap<(u32, u32), u32> = HashMap::new();
    let mut builtin_wg: Option<u32> = None;
    let mut vars: Vec<(u32, u32, u32)> = Vec::new(); // (pointer type, id, storage class)
    let mut local_size = [1u32; 3];
    let mut names: HashMap<u32, String> = HashMap::new();
    let mut member_names: HashMap<(u32, u32), String> = HashMap::new();
    let mut spec_defaults: HashMap<u32, u32> = HashMap::new(); // result id -> default of an OpSpecConstant*

    let mut i = 5;
    while i < words.len() {
        let wc = (words[i] >> 16) as usize;
        let op = (words[i] & 0xffff) as u16;
        if wc == 0 || i + wc > words.len() {
            return Err(format!("malformed instruction at word {i}"));
        }
        let a = &words[i + 1..i + wc];
        match op {
            OP_NAME if !a.is_empty() => {
                names.insert(a[0], literal_string(&a[1..]));
            }
            OP_MEMBER_NAME if a.len() >= 2 => {
                member_names.insert((a[0], a[1]), literal_string(&a[2..]));
            }
            OP_EXECUTION_MODE if a.len() >= 5 && a[1] == MODE_LOCAL_SIZE => local_size = [a[2], a[3], a[4]],
            OP_TYPE_BOOL => {
                types.insert(a[0], Ty::Scalar(Scalar { kind: ScalarKind::Bool, bytes: 4 }));
            }
            OP_TYPE_INT if a.len() >= 3 => {
                let kind = if a[2] != 0 { ScalarKind::Int } else { ScalarKind::Uint };
                types.insert(a[0], Ty::Scalar(Scalar { kind, bytes: a[1] / 8 }));
            }
            OP_TYPE_FLOAT if a.len() >= 2 => {
                types.insert(a[0], Ty::Scalar(Scalar { kind: ScalarKind::Float, bytes: a[1] / 8 }));
            }
            OP_TYPE_VECTOR | OP_TYPE_MATRIX => {
                types.insert(a[0], Ty::Vector(a[1], a[2]));
            }
            OP_TYPE_ARRAY => {
                types.insert(a[0], Ty::Array(a[1], a[2]));
            }
            OP_TYPE_STRUCT => {
                types.insert(a[0], Ty::Struct(a[1..].to_vec()));
            }
            OP_TYPE_POINTER => {
                types.insert(a[0], Ty::Pointer(a[2]));
            }
            OP_CONSTANT | OP_SPEC_CONSTANT if a.len() >= 3 => {
                constants.insert(a[1], a[2]);
                if op == OP_SPEC_CONSTANT {
                    spec_defaults.insert(a[1], a[2]);
                }
            }
            OP_SPEC_CONSTANT_TRUE | OP_SPEC_CONSTANT_FALSE if a.len() >= 2 => {
                spec_defaults.insert(a[1], u32::from(op == OP_SPEC_CONSTANT_TRUE));
            }
            OP_CONSTANT_COMPOSITE | OP_SPEC_CONSTANT_COMPOSITE => {
                composites.insert(a[1], a[2..].to_vec());
            }
            OP_VARIABLE => vars.push((a[0], a[1], a[2])),
            OP_DECORATE if a.len() >= 3 => match a[1] {
                DEC_BINDING => {
                    bindings.insert(a[0], a[2]);
                }
                DEC_SPEC_ID => {
                    spec_const_ids.insert(a[0], a[2]);
                }
                DEC_ARRAY_STRIDE => {
                    strides.insert(a[0], a[2]);
                }
                DEC_BUILTIN if a[2] == BUILTIN_WORKGROUP_SIZE => builtin_wg = Some(a[0]),
                _ => {}
            },
            OP_MEMBER_DECORATE if a.len() >= 4 && a[2] == DEC_OFFSET => {
                offsets.insert((a[0], a[1]), a[3]);
            }
            _ => {}
        }
        i += wc;
    }

    let mut spec_constants: Vec<SpecConstant> = spec_const_ids
        .iter()
        .filter_map(|(id, &spec_id)| {
            let default = *spec_defaults.get(id)?;
            Some(SpecConstant { id: spec_id, name: names.get(id).cloned().unwrap_or_default(), default })
        })
        .collect();
    spec_constants.sort_by_key(|c| c.id);

    // Specialisation overrides replace the default values of the constants that carry a SpecId.
    for (&id, &spec_id) in &spec_const_ids {
        if let Some(&(_, v)) = spec.iter().find(|(s, _)| *s == spec_id) {
            constants.insert(id, v);
        }
    }
    if let Some(wg) = builtin_wg {
        let parts = composites.get(&wg).ok_or("WorkgroupSize built-in is not a composite constant")?;
        for (k, p) in parts.iter().take(3).enumerate() {
            local_size[k] = *constants.get(p).ok_or("WorkgroupSize component is not a constant")?;
        }
    }

    let size_of = |t: u32| -> Result<u32, String> { type_size(t, &types, &constants, &strides, &offsets, 0) };
    let mut push_constant_bytes = 0;
    let mut push_members = Vec::new();
    let mut shared_bytes = 0;
    let mut binding_list = Vec::new();
    let mut texel_list = Vec::new();
    for &(ptr, id, sc) in &vars {
        let pointee = match types.get(&ptr) {
            Some(Ty::Pointer(t)) => *t,
            _ => continue,
        };
        match sc {
            SC_PUSH_CONSTANT => {
                push_constant_bytes = size_of(pointee)?;
                if let Some(Ty::Struct(members)) = types.get(&pointee) {
                    push_members = members
                        .iter()
                        .enumerate()
                        .map(|(m, &mt)| {
                            let m = m as u32;
                            Ok(PushMember {
                                name: member_names.get(&(pointee, m)).cloned().unwrap_or_default(),
                                offset: *offsets
                                    .get(&(pointee, m))
                                    .ok_or_else(|| format!("push-constant member {m} has no Offset"))?,
                                size: size_of(mt)?,
                                scalar: scalar_of(mt, &types, 0),
                            })
                        })
                        .collect::<Result<_, String>>()?;
                }
            }
            SC_WORKGROUP => shared_bytes += size_of(pointee)?,
            SC_STORAGE_BUFFER | SC_UNIFORM => {
                if let Some(&b) = bindings.get(&id) {
                    binding_list.push(b);
                }
            }
            SC_UNIFORM_CONSTANT => {
                if let Some(&b) = bindings.get(&id) {
                    texel_list.push(b);
                }
            }
            _ => {}
        }
    }
    binding_list.sort_unstable();
    binding_list.dedup();
    texel_list.sort_unstable();
    texel_list.dedup();
    Ok(ShaderInfo {
        bindings: binding_list,
        texel_bindings: texel_list,
        local_size,
        push_constant_bytes,
        push_members,
        spec_constants,
        shared_bytes,
    })
}

/// A SPIR-V literal string: UTF-8 bytes packed little-endian into words, NUL-terminated.
fn literal_string(words: &[u32]) -> String {
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).take_while(|&b| b != 0).collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

/// The component scalar of a scalar, vector, matrix or array type.
fn scalar_of(t: u32, types: &HashMap<u32, Ty>, depth: u32) -> Option<Scalar> {
    if depth > 16 {
        return None;
    }
    match types.get(&t)? {
        Ty::Scalar(s) => Some(*s),
        Ty::Vector(c, _) | Ty::Array(c, _) => scalar_of(*c, types, depth + 1),
        Ty::Struct(_) | Ty::Pointer(_) => None,
    }
}

fn type_size(
    t: u32,
    types: &HashMap<u32, Ty>,
    constants: &HashMap<u32, u32>,
    strides: &HashMap<u32, u32>,
    offsets: &HashMap<(u32, u32), u32>,
    depth: u32,
) -> Result<u32, String> {
    if depth > 16 {
        return Err("type nesting too deep".into());
    }
    let rec = |t| type_size(t, types, constants, strides, offsets, depth + 1);
    match types.get(&t).ok_or_else(|| format!("unknown type id {t}"))? {
        Ty::Scalar(s) => Ok(s.bytes),
        Ty::Vector(c, n) => Ok(rec(*c)? * n),
        Ty::Array(elem, len_id) => {
            let len = *constants.get(len_id).ok_or("array length is not a constant")?;
            let stride = match strides.get(&t) {
                Some(&s) => s,
                None => rec(*elem)?,
            };
            Ok(stride * len)
        }
        Ty::Struct(members) => {
            let mut end = 0;
            let mut packed = 0;
            for (m, &mt) in members.iter().enumerate() {
                let size = rec(mt)?;
                let off = offsets.get(&(t, m as u32)).copied().unwrap_or(packed);
                end = end.max(off + size);
                packed = off + size;
            }
            Ok(end)
        }
        Ty::Pointer(..) => Ok(8),
    }
}
