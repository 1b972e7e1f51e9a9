//! Push-constant layouts declared once on the Rust side and compared with the shader's block member by member.
//!
//! [`push_constants!`](crate::push_constants) declares a `#[repr(C)]` bytemuck `Pod` struct and implements
//! [`PushLayout`] for it, the field list derived from the struct itself (`offset_of!`, `size_of`), so it cannot
//! drift. `Kernel::new` / `Kernel::with_spec` then require, for every member of the shader's push block in order,
//! a Rust field of the same name, byte offset, size and scalar type ([`check_push_layout`]). Rust fields past the
//! shader's members are allowed only where they start at or after the block's end: the explicit padding a `Pod`
//! struct needs up to its alignment (a struct with a `u64` rounds up to 8 bytes), which the shader never reads.

use super::spirv::{PushMember, Scalar, ScalarKind, ShaderInfo};
use bytemuck::Pod;

/// One field of a push-constant struct, as [`push_constants!`](crate::push_constants) derives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PushField {
    pub name: &'static str,
    pub offset: u32,
    pub size: u32,
    pub scalar: Scalar,
}

/// A push-constant struct with its field layout. Implement it with [`push_constants!`](crate::push_constants).
pub trait PushLayout: Pod {
    /// The fields in declaration order.
    const FIELDS: &'static [PushField];
}

/// Field types a push-constant struct may hold: the scalar each maps to in GLSL (`[T; N]` is an array of `T`).
pub trait PushScalar {
    const SCALAR: Scalar;
}

macro_rules! push_scalar {
    ($($t:ty => $kind:ident),*) => {$(
        impl PushScalar for $t {
            const SCALAR: Scalar = Scalar { kind: ScalarKind::$kind, bytes: std::mem::size_of::<$t>() as u32 };
        }
    )*};
}
push_scalar!(u32 => Uint, i32 => Int, f32 => Float, u64 => Uint, i64 => Int, f64 => Float);

impl<T: PushScalar, const N: usize> PushScalar for [T; N] {
    const SCALAR: Scalar = T::SCALAR;
}

/// Declares a push-constant struct (`#[repr(C)]`, `Copy`, `Clone`, `Pod`, `Zeroable`) and its [`PushLayout`]:
///
/// ```
/// msnerf::push_constants! {
///     struct FillPush { n: u32, offset: u32, value: u32 }
/// }
/// use msnerf::gpu::push::PushLayout;
/// assert_eq!(std::mem::size_of::<FillPush>(), 12);
/// assert_eq!(FillPush::FIELDS.iter().map(|f| f.name).collect::<Vec<_>>(), ["n", "offset", "value"]);
/// ```
///
/// Field names are the GLSL member names. Attributes (docs, further derives) pass through.
#[macro_export]
macro_rules! push_constants {
    ($(
        $(#[$meta:meta])*
        $vis:vis struct $name:ident {
            $($(#[$fmeta:meta])* $fvis:vis $field:ident : $ty:ty),* $(,)?
        }
    )*) => {$(
        $(#[$meta])*
        #[repr(C)]
        #[derive(Copy, Clone, ::bytemuck::Pod, ::bytemuck::Zeroable)]
        $vis struct $name {
            $($(#[$fmeta])* $fvis $field: $ty),*
        }

        impl $crate::gpu::PushLayout for $name {
            const FIELDS: &'static [$crate::gpu::PushField] = &[$(
                $crate::gpu::PushField {
                    name: stringify!($field),
                    offset: ::std::mem::offset_of!($name, $field) as u32,
                    size: ::std::mem::size_of::<$ty>() as u32,
                    scalar: <$ty as $crate::gpu::push::PushScalar>::SCALAR,
                }
            ),*];
        }
    )*};
}

/// Compares the Rust fields with the shader's push block, member by member; the error names the first member
/// that differs and both sides' offsets.
pub fn check_push_layout(fields: &[PushField], info: &ShaderInfo) -> Result<(), String> {
    for (k, m) in info.push_members.iter().enumerate() {
        let Some(f) = fields.get(k) else {
            return Err(format!(
                "push constant `{}` (offset {}) has no Rust field: the Rust struct ends after {k} fields",
                m.name, m.offset
            ));
        };
        if let Some(msg) = field_mismatch(f, m) {
            return Err(msg);
        }
    }
    let block_end = info.push_constant_bytes;
    if let Some(f) = fields.iter().skip(info.push_members.len()).find(|f| f.offset < block_end) {
        return Err(format!(
            "Rust field `{}` at offset {} is not in the shader's push block ({} bytes)",
            f.name, f.offset, block_end
        ));
    }
    Ok(())
}

fn field_mismatch(f: &PushField, m: &PushMember) -> Option<String> {
    if f.name != m.name {
        return Some(format!(
            "push constant `{}` at offset {} in the shader, but the Rust field there is `{}` at offset {}",
            m.name, m.offset, f.name, f.offset
        ));
    }
    if f.offset != m.offset {
        return Some(format!(
            "push constant `{}` is at offset {} in the shader, at offset {} in Rust",
            m.name, m.offset, f.offset
        ));
    }
    if f.size != m.size || m.scalar != Some(f.scalar) {
        let shader_ty = m.scalar.map_or("an aggregate".to_string(), |s| s.to_string());
        return Some(format!(
            "push constant `{}` (offset {}) is {} bytes of {shader_ty} in the shader, {} bytes of {} in Rust",
            m.name, m.offset, m.size, f.size, f.scalar
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    crate::push_constants! {
        struct Sample { w: u64, n: u32, scale: f32, pad: [u32; 2] }
    }

    fn member(name: &str, offset: u32, size: u32, kind: ScalarKind, bytes: u32) -> PushMember {
        PushMember { name: name.into(), offset, size, scalar: Some(Scalar { kind, bytes }) }
    }

    fn info(members: Vec<PushMember>, bytes: u32) -> ShaderInfo {
        ShaderInfo {
            bindings: vec![],
            texel_bindings: vec![],
            local_size: [1, 1, 1],
            push_constant_bytes: bytes,
            push_members: members,
            spec_constants: vec![],
            shared_bytes: 0,
        }
    }

    #[test]
    fn fields_follow_the_struct() {
        let names: Vec<_> = Sample::FIELDS.iter().map(|f| (f.name, f.offset, f.size)).collect();
        assert_eq!(names, [("w", 0, 8), ("n", 8, 4), ("scale", 12, 4), ("pad", 16, 8)]);
        assert_eq!(Sample::FIELDS[0].scalar, Scalar { kind: ScalarKind::Uint, bytes: 8 });
        assert_eq!(Sample::FIELDS[3].scalar, Scalar { kind: ScalarKind::Uint, bytes: 4 });
    }

    #[test]
    fn layouts_compare_by_name_offset_size_and_type() {
        let good = vec![
            member("w", 0, 8, ScalarKind::Uint, 8),
            member("n", 8, 4, ScalarKind::Uint, 4),
            member("scale", 12, 4, ScalarKind::Float, 4),
            member("pad", 16, 8, ScalarKind::Uint, 4),
        ];
        assert_eq!(check_push_layout(Sample::FIELDS, &info(good.clone(), 24)), Ok(()));
        // Trailing Rust padding past the block's end is allowed, inside it is not.
        assert_eq!(check_push_layout(Sample::FIELDS, &info(good[..3].to_vec(), 16)), Ok(()));
        assert!(check_push_layout(Sample::FIELDS, &info(good[..3].to_vec(), 20)).unwrap_err().contains("`pad`"));
        let mut swapped = good.clone();
        swapped[1].name = "scale".into();
        swapped[2].name = "n".into();
        let err = check_push_layout(Sample::FIELDS, &info(swapped, 24)).unwrap_err();
        assert!(err.contains("`scale` at offset 8") && err.contains("`n` at offset 8"), "{err}");
        let mut float = good.clone();
        float[1] = member("n", 8, 4, ScalarKind::Float, 4);
        let err = check_push_layout(Sample::FIELDS, &info(float, 24)).unwrap_err();
        assert!(err.contains("f32 in the shader") && err.contains("u32 in Rust"), "{err}");
        let mut moved = good;
        moved[2].offset = 16;
        let err = check_push_layout(Sample::FIELDS, &info(moved, 24)).unwrap_err();
        assert!(err.contains("offset 16 in the shader, at offset 12 in Rust"), "{err}");
    }
}
