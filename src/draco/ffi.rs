//! The C ABI of our shim over Draco (`shim/draco_shim.h`) and the types that own its handles and
//! error buffer. Every `unsafe` call goes through `super`, which checks pointers and lengths.

use std::ffi::c_void;
use std::os::raw::c_char;

pub const OK: i32 = 0;
pub const ERR_INVALID_ARGUMENT: i32 = 1;
pub const ERR_ENCODE: i32 = 2;
pub const ERR_DECODE: i32 = 3;
pub const ERR_UNSUPPORTED: i32 = 4;
pub const ERR_OUT_OF_MEMORY: i32 = 5;
pub const ERR_INTERNAL: i32 = 6;

pub const KIND_POSITION: i32 = 0;
pub const KIND_NORMAL: i32 = 1;
pub const KIND_COLOR: i32 = 2;
pub const KIND_TEX_COORD: i32 = 3;
pub const KIND_GENERIC: i32 = 4;

pub const DTYPE_F32: i32 = 0;
pub const DTYPE_U8: i32 = 1;
pub const DTYPE_U16: i32 = 2;
pub const DTYPE_U32: i32 = 3;
pub const DTYPE_I8: i32 = 4;
pub const DTYPE_I16: i32 = 5;
pub const DTYPE_I32: i32 = 6;

pub const METHOD_EDGEBREAKER: i32 = 0;
pub const METHOD_SEQUENTIAL: i32 = 1;

#[repr(C)]
pub struct Attribute {
    pub kind: i32,
    pub dtype: i32,
    pub components: u32,
    pub normalized: i32,
    pub quantization_bits: i32,
    pub data: *const c_void,
    pub num_values: u64,
}

#[repr(C)]
pub struct EncodeOptions {
    pub encode_speed: i32,
    pub decode_speed: i32,
    pub method: i32,
}

#[repr(C)]
#[derive(Default)]
pub struct AttributeInfo {
    pub unique_id: u32,
    pub kind: i32,
    pub dtype: i32,
    pub components: u32,
    pub normalized: i32,
}

#[repr(C)]
pub struct Encoded {
    _private: [u8; 0],
}
#[repr(C)]
pub struct Mesh {
    _private: [u8; 0],
}

extern "C" {
    pub fn bt_draco_encode(
        attrs: *const Attribute,
        num_attrs: u32,
        num_points: u64,
        indices: *const u32,
        num_indices: u64,
        opts: *const EncodeOptions,
        out: *mut *mut Encoded,
        err: *mut c_char,
        err_cap: usize,
    ) -> i32;
    pub fn bt_draco_encoded_data(e: *const Encoded) -> *const u8;
    pub fn bt_draco_encoded_size(e: *const Encoded) -> u64;
    pub fn bt_draco_encoded_unique_id(e: *const Encoded, i: u32) -> u32;
    pub fn bt_draco_encoded_num_points(e: *const Encoded) -> u64;
    pub fn bt_draco_encoded_num_faces(e: *const Encoded) -> u64;
    pub fn bt_draco_encoded_free(e: *mut Encoded);

    pub fn bt_draco_decode(
        data: *const u8,
        len: u64,
        out: *mut *mut Mesh,
        err: *mut c_char,
        err_cap: usize,
    ) -> i32;
    pub fn bt_draco_mesh_num_points(m: *const Mesh) -> u64;
    pub fn bt_draco_mesh_num_faces(m: *const Mesh) -> u64;
    pub fn bt_draco_mesh_num_attributes(m: *const Mesh) -> u32;
    pub fn bt_draco_mesh_attribute_info(m: *const Mesh, i: u32, out: *mut AttributeInfo) -> i32;
    pub fn bt_draco_mesh_copy_indices(m: *const Mesh, out: *mut u32, cap: u64) -> i32;
    pub fn bt_draco_mesh_copy_attribute(
        m: *const Mesh,
        i: u32,
        out: *mut c_void,
        cap_bytes: u64,
    ) -> i32;
    pub fn bt_draco_mesh_free(m: *mut Mesh);
}

/// Error-message buffer handed to the shim.
pub(super) struct ErrBuf([u8; 512]);

impl ErrBuf {
    pub(super) fn new() -> Self {
        ErrBuf([0; 512])
    }
    pub(super) fn ptr(&mut self) -> *mut c_char {
        self.0.as_mut_ptr().cast()
    }
    pub(super) fn cap(&self) -> usize {
        self.0.len()
    }
    pub(super) fn message(&self) -> String {
        let end = self.0.iter().position(|&b| b == 0).unwrap_or(self.0.len());
        String::from_utf8_lossy(&self.0[..end]).into_owned()
    }
    pub(super) fn to_error(
        &self,
        status: i32,
        default: fn(String) -> super::DracoError,
    ) -> super::DracoError {
        let mut msg = self.message();
        if msg.is_empty() {
            msg = "no message".into();
        }
        if status == OK {
            return super::DracoError::Internal(format!(
                "shim returned OK without a result: {msg}"
            ));
        }
        super::status_error(status, msg, default)
    }
}

/// Owns a `bt_draco_encoded` handle.
pub(super) struct EncodedHandle(pub(super) *mut Encoded);
impl Drop for EncodedHandle {
    fn drop(&mut self) {
        // SAFETY: the handle came from a successful bt_draco_encode and is freed only here.
        unsafe { bt_draco_encoded_free(self.0) }
    }
}

/// Owns a `bt_draco_mesh` handle.
pub(super) struct MeshHandle(pub(super) *mut Mesh);
impl Drop for MeshHandle {
    fn drop(&mut self) {
        // SAFETY: the handle came from a successful bt_draco_decode and is freed only here.
        unsafe { bt_draco_mesh_free(self.0) }
    }
}
