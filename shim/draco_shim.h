/*
 * bimtiles Draco shim: a small C ABI over Google Draco's C++ mesh encoder and
 * decoder (Debian's libdraco 1.5.5 ships no C API).
 *
 * Rules of this ABI:
 *  - every function returns a status code (BT_DRACO_OK == 0 on success) or a
 *    plain value; no C++ exception ever crosses it (all entry points catch);
 *  - error text is written, NUL-terminated and truncated, into the caller's
 *    buffer `err` of `err_cap` bytes (may be NULL / 0);
 *  - memory made here is owned by an opaque handle and released only by the
 *    matching *_free function; the caller owns everything it passes in and
 *    the shim never keeps a pointer to caller memory after returning.
 *
 * The Rust side (src/draco/) is the only user; keep the two in sync.
 */
#ifndef BIMTILES_DRACO_SHIM_H_
#define BIMTILES_DRACO_SHIM_H_

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Status codes. */
#define BT_DRACO_OK 0
#define BT_DRACO_ERR_INVALID_ARGUMENT 1
#define BT_DRACO_ERR_ENCODE 2
#define BT_DRACO_ERR_DECODE 3
#define BT_DRACO_ERR_UNSUPPORTED 4
#define BT_DRACO_ERR_OUT_OF_MEMORY 5
#define BT_DRACO_ERR_INTERNAL 6

/* Attribute kinds: same numbers as draco::GeometryAttribute::Type. */
#define BT_DRACO_KIND_POSITION 0
#define BT_DRACO_KIND_NORMAL 1
#define BT_DRACO_KIND_COLOR 2
#define BT_DRACO_KIND_TEX_COORD 3
#define BT_DRACO_KIND_GENERIC 4

/* Component data types (ours, not Draco's numbering). */
#define BT_DRACO_DTYPE_F32 0
#define BT_DRACO_DTYPE_U8 1
#define BT_DRACO_DTYPE_U16 2
#define BT_DRACO_DTYPE_U32 3
#define BT_DRACO_DTYPE_I8 4
#define BT_DRACO_DTYPE_I16 5
#define BT_DRACO_DTYPE_I32 6

/* Connectivity coding. */
#define BT_DRACO_METHOD_EDGEBREAKER 0
#define BT_DRACO_METHOD_SEQUENTIAL 1

/* One input attribute: `num_points * components` values of `dtype` at `data`.
 * quantization_bits: 0 = lossless; 1..30 for F32 data only. */
typedef struct bt_draco_attribute {
  int32_t kind;
  int32_t dtype;
  uint32_t components;
  int32_t normalized;
  int32_t quantization_bits;
  const void *data;
  uint64_t num_values; /* total scalar values = num_points * components */
} bt_draco_attribute;

typedef struct bt_draco_encode_options {
  int32_t encode_speed; /* 0 (best compression) .. 10 (fastest) */
  int32_t decode_speed; /* 0 .. 10 */
  int32_t method;       /* BT_DRACO_METHOD_* */
} bt_draco_encode_options;

/* Result of an encode: the Draco bitstream plus what the encoder reports. */
typedef struct bt_draco_encoded bt_draco_encoded;

/* Encodes a triangle mesh. `indices` holds 3 * num_faces point indices, each
 * < num_points. On success *out is a new handle (free with
 * bt_draco_encoded_free); on failure *out is NULL. */
int32_t bt_draco_encode(const bt_draco_attribute *attrs, uint32_t num_attrs,
                        uint64_t num_points, const uint32_t *indices,
                        uint64_t num_indices,
                        const bt_draco_encode_options *opts,
                        bt_draco_encoded **out, char *err, size_t err_cap);

const uint8_t *bt_draco_encoded_data(const bt_draco_encoded *e);
uint64_t bt_draco_encoded_size(const bt_draco_encoded *e);
/* Draco unique id of input attribute i (the id that goes into the glTF
 * KHR_draco_mesh_compression "attributes" map); UINT32_MAX if out of range. */
uint32_t bt_draco_encoded_unique_id(const bt_draco_encoded *e, uint32_t i);
/* Points / faces as counted by the encoder (what a decoder will produce). */
uint64_t bt_draco_encoded_num_points(const bt_draco_encoded *e);
uint64_t bt_draco_encoded_num_faces(const bt_draco_encoded *e);
void bt_draco_encoded_free(bt_draco_encoded *e);

/* A decoded mesh. */
typedef struct bt_draco_mesh bt_draco_mesh;

typedef struct bt_draco_attribute_info {
  uint32_t unique_id;
  int32_t kind;  /* BT_DRACO_KIND_*, or the raw Draco type if unknown */
  int32_t dtype; /* BT_DRACO_DTYPE_* of the values bt_draco_mesh_copy_attribute writes */
  uint32_t components;
  int32_t normalized;
} bt_draco_attribute_info;

/* Decodes a Draco mesh bitstream. Point clouds are rejected with
 * BT_DRACO_ERR_UNSUPPORTED. On success *out is a new handle (free with
 * bt_draco_mesh_free); on failure *out is NULL. The decoded mesh is checked
 * (face indices < num_points, attribute maps in range) before it is returned. */
int32_t bt_draco_decode(const uint8_t *data, uint64_t len, bt_draco_mesh **out,
                        char *err, size_t err_cap);

uint64_t bt_draco_mesh_num_points(const bt_draco_mesh *m);
uint64_t bt_draco_mesh_num_faces(const bt_draco_mesh *m);
uint32_t bt_draco_mesh_num_attributes(const bt_draco_mesh *m);
int32_t bt_draco_mesh_attribute_info(const bt_draco_mesh *m, uint32_t i,
                                     bt_draco_attribute_info *out);
/* Writes 3 * num_faces indices; `cap` is the number of uint32 slots at out. */
int32_t bt_draco_mesh_copy_indices(const bt_draco_mesh *m, uint32_t *out,
                                   uint64_t cap);
/* Writes num_points * components values of the attribute's info.dtype, one
 * entry per point (de-indexed); `cap_bytes` is the size of `out` in bytes. */
int32_t bt_draco_mesh_copy_attribute(const bt_draco_mesh *m, uint32_t i,
                                     void *out, uint64_t cap_bytes);
void bt_draco_mesh_free(bt_draco_mesh *m);

#ifdef __cplusplus
}
#endif

#endif /* BIMTILES_DRACO_SHIM_H_ */
