//! Minimal SPIR-V reflection (kajiya reads layouts from SPIR-V too): the storage-buffer bindings a kernel
//! declares, its workgroup size (literal `LocalSize`, or the `WorkgroupSize` built-in made of specialisation
//! constants, resolved with the values the pipeline sets), its push-constant block size and its shared memory.
//! `Kernel::new` checks these against the Rust side so a mismatch fails at creation, not as garbage output.

use std::collections::HashMap;

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShaderInfo {
    /// Sorted binding numbers (descriptor set 0) of storage and uniform buffers.
    pub bindings: Vec<u32>,
    pub local_size: [u32; 3],
    pub push_constant_bytes: u32,
    pub shared_bytes: u32,
}

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
const SC_UNIFORM: u32 = 2;
const SC_WORKGROUP: u32 = 4;
const SC_PUSH_CONSTANT: u32 = 9;
const SC_STORAGE_BUFFER: u32 = 12;

#[derive(Clone, Debug)]
enum Ty {
    Scalar(u32),
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

    let mut i = 5;
    while i < words.len() {
        let wc = (words[i] >> 16) as usize;
        let op = (words[i] & 0xffff) as u16;
        if wc == 0 || i + wc > words.len() {
            return Err(format!("malformed instruction at word {i}"));
        }
        let a = &words[i + 1..i + wc];
        match op {
            OP_EXECUTION_MODE if a.len() >= 5 && a[1] == MODE_LOCAL_SIZE => local_size = [a[2], a[3], a[4]],
            OP_TYPE_BOOL => {
                types.insert(a[0], Ty::Scalar(4));
            }
            OP_TYPE_INT | OP_TYPE_FLOAT => {
                types.insert(a[0], Ty::Scalar(a[1] / 8));
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
    let mut shared_bytes = 0;
    let mut binding_list = Vec::new();
    for &(ptr, id, sc) in &vars {
        let pointee = match types.get(&ptr) {
            Some(Ty::Pointer(t)) => *t,
            _ => continue,
        };
        match sc {
            SC_PUSH_CONSTANT => push_constant_bytes = size_of(pointee)?,
            SC_WORKGROUP => shared_bytes += size_of(pointee)?,
            SC_STORAGE_BUFFER | SC_UNIFORM => {
                if let Some(&b) = bindings.get(&id) {
                    binding_list.push(b);
                }
            }
            _ => {}
        }
    }
    binding_list.sort_unstable();
    binding_list.dedup();
    Ok(ShaderInfo { bindings: binding_list, local_size, push_constant_bytes, shared_bytes })
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
        Ty::Scalar(b) => Ok(*b),
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
