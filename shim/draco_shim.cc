// bimtiles Draco shim: C ABI over Draco's C++ mesh encoder/decoder.
// See draco_shim.h for the contract (status codes, ownership, no exceptions).
#include "draco_shim.h"

#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include "draco/attributes/geometry_attribute.h"
#include "draco/attributes/point_attribute.h"
#include "draco/compression/config/compression_shared.h"
#include "draco/compression/decode.h"
#include "draco/compression/expert_encode.h"
#include "draco/core/decoder_buffer.h"
#include "draco/core/encoder_buffer.h"
#include "draco/mesh/mesh.h"

struct bt_draco_encoded {
  draco::EncoderBuffer buffer;
  std::vector<uint32_t> unique_ids;
  uint64_t num_points = 0;
  uint64_t num_faces = 0;
};

struct bt_draco_mesh {
  std::unique_ptr<draco::Mesh> mesh;
};

namespace {

// Largest point / face count we accept: Draco indexes with int32 in places.
constexpr uint64_t kMaxCount = static_cast<uint64_t>(std::numeric_limits<int32_t>::max());

void set_err(char *err, size_t cap, const std::string &msg) {
  if (err == nullptr || cap == 0) return;
  size_t n = msg.size() < cap - 1 ? msg.size() : cap - 1;
  std::memcpy(err, msg.data(), n);
  err[n] = '\0';
}

int32_t fail(char *err, size_t cap, int32_t code, const std::string &msg) {
  set_err(err, cap, msg);
  return code;
}

bool dtype_to_draco(int32_t dtype, draco::DataType *out, size_t *size) {
  switch (dtype) {
    case BT_DRACO_DTYPE_F32: *out = draco::DT_FLOAT32; *size = 4; return true;
    case BT_DRACO_DTYPE_U8: *out = draco::DT_UINT8; *size = 1; return true;
    case BT_DRACO_DTYPE_U16: *out = draco::DT_UINT16; *size = 2; return true;
    case BT_DRACO_DTYPE_U32: *out = draco::DT_UINT32; *size = 4; return true;
    case BT_DRACO_DTYPE_I8: *out = draco::DT_INT8; *size = 1; return true;
    case BT_DRACO_DTYPE_I16: *out = draco::DT_INT16; *size = 2; return true;
    case BT_DRACO_DTYPE_I32: *out = draco::DT_INT32; *size = 4; return true;
    default: return false;
  }
}

// Output dtype for a decoded Draco data type (-1 = not supported).
int32_t draco_to_out_dtype(draco::DataType dt) {
  switch (dt) {
    case draco::DT_FLOAT32:
    case draco::DT_FLOAT64: return BT_DRACO_DTYPE_F32;
    case draco::DT_UINT8:
    case draco::DT_BOOL: return BT_DRACO_DTYPE_U8;
    case draco::DT_UINT16: return BT_DRACO_DTYPE_U16;
    case draco::DT_UINT32: return BT_DRACO_DTYPE_U32;
    case draco::DT_INT8: return BT_DRACO_DTYPE_I8;
    case draco::DT_INT16: return BT_DRACO_DTYPE_I16;
    case draco::DT_INT32: return BT_DRACO_DTYPE_I32;
    default: return -1;
  }
}

size_t out_dtype_size(int32_t dtype) {
  switch (dtype) {
    case BT_DRACO_DTYPE_U8:
    case BT_DRACO_DTYPE_I8: return 1;
    case BT_DRACO_DTYPE_U16:
    case BT_DRACO_DTYPE_I16: return 2;
    default: return 4;
  }
}

int32_t encode_impl(const bt_draco_attribute *attrs, uint32_t num_attrs, uint64_t num_points,
                    const uint32_t *indices, uint64_t num_indices,
                    const bt_draco_encode_options *opts, bt_draco_encoded **out, char *err,
                    size_t cap) {
  if (attrs == nullptr || num_attrs == 0)
    return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "no attributes");
  if (indices == nullptr || num_indices == 0)
    return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "no triangles");
  if (num_indices % 3 != 0)
    return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "index count is not a multiple of 3");
  if (num_points == 0 || num_points > kMaxCount || num_indices / 3 > kMaxCount)
    return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "point or face count out of range");
  if (opts == nullptr) return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "no options");
  if (opts->encode_speed < 0 || opts->encode_speed > 10 || opts->decode_speed < 0 ||
      opts->decode_speed > 10)
    return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "speed must be in 0..=10");
  if (opts->method != BT_DRACO_METHOD_EDGEBREAKER && opts->method != BT_DRACO_METHOD_SEQUENTIAL)
    return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "unknown encoding method");

  draco::Mesh mesh;
  mesh.set_num_points(static_cast<uint32_t>(num_points));
  int positions = 0;
  std::vector<int> att_ids(num_attrs, -1);
  for (uint32_t i = 0; i < num_attrs; ++i) {
    const bt_draco_attribute &a = attrs[i];
    const std::string which = "attribute " + std::to_string(i) + ": ";
    if (a.kind < BT_DRACO_KIND_POSITION || a.kind > BT_DRACO_KIND_GENERIC)
      return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, which + "unknown kind");
    if (a.kind == BT_DRACO_KIND_POSITION) ++positions;
    draco::DataType dt;
    size_t elem = 0;
    if (!dtype_to_draco(a.dtype, &dt, &elem))
      return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, which + "unknown data type");
    if (a.components < 1 || a.components > 4)
      return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, which + "components must be 1..=4");
    if (a.data == nullptr || a.num_values != num_points * a.components)
      return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT,
                  which + "value count != num_points * components");
    if (a.quantization_bits < 0 || a.quantization_bits > 30)
      return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT,
                  which + "quantization bits must be 0..=30");
    if (a.quantization_bits > 0 && a.dtype != BT_DRACO_DTYPE_F32)
      return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT,
                  which + "quantization applies to f32 data only");

    const int64_t stride = static_cast<int64_t>(elem * a.components);
    draco::GeometryAttribute ga;
    ga.Init(static_cast<draco::GeometryAttribute::Type>(a.kind), nullptr,
            static_cast<uint8_t>(a.components), dt, a.normalized != 0, stride, 0);
    const int id = mesh.AddAttribute(ga, /*identity_mapping=*/true,
                                     static_cast<uint32_t>(num_points));
    if (id < 0) return fail(err, cap, BT_DRACO_ERR_ENCODE, which + "Draco refused the attribute");
    draco::PointAttribute *pa = mesh.attribute(id);
    if (pa == nullptr || pa->buffer() == nullptr ||
        static_cast<uint64_t>(pa->buffer()->data_size()) <
            num_points * static_cast<uint64_t>(stride))
      return fail(err, cap, BT_DRACO_ERR_INTERNAL, which + "attribute buffer not allocated");
    pa->buffer()->Write(0, a.data, static_cast<size_t>(num_points) * static_cast<size_t>(stride));
    att_ids[i] = id;
  }
  if (positions != 1)
    return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "exactly one POSITION attribute is required");

  const uint64_t num_faces = num_indices / 3;
  mesh.SetNumFaces(static_cast<size_t>(num_faces));
  for (uint64_t f = 0; f < num_faces; ++f) {
    draco::Mesh::Face face;
    for (int c = 0; c < 3; ++c) {
      const uint32_t v = indices[3 * f + c];
      if (v >= num_points)
        return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT,
                    "index " + std::to_string(v) + " at position " + std::to_string(3 * f + c) +
                        " >= point count " + std::to_string(num_points));
      face[c] = draco::PointIndex(v);
    }
    mesh.SetFace(draco::FaceIndex(static_cast<uint32_t>(f)), face);
  }

  draco::ExpertEncoder enc(mesh);
  enc.SetSpeedOptions(opts->encode_speed, opts->decode_speed);
  enc.SetEncodingMethod(opts->method == BT_DRACO_METHOD_SEQUENTIAL ? draco::MESH_SEQUENTIAL_ENCODING
                                                                   : draco::MESH_EDGEBREAKER_ENCODING);
  for (uint32_t i = 0; i < num_attrs; ++i) {
    if (attrs[i].quantization_bits > 0)
      enc.SetAttributeQuantization(att_ids[i], attrs[i].quantization_bits);
    // Normals predicted from the decoded positions of the neighbouring triangles (Draco picks
    // this only below speed 4; plain difference coding above). Measured on the shared models
    // at speed 7: -10 to -15 % of the whole stream for flat-shaded BIM elements (duplex,
    // IfcOpenHouse), -2 % for LoD3_Railway. Needs Edgebreaker's connectivity.
    if (attrs[i].kind == BT_DRACO_KIND_NORMAL && opts->method != BT_DRACO_METHOD_SEQUENTIAL)
      enc.SetAttributePredictionScheme(att_ids[i], draco::MESH_PREDICTION_GEOMETRIC_NORMAL);
  }
  enc.SetTrackEncodedProperties(true);

  std::unique_ptr<bt_draco_encoded> res(new bt_draco_encoded());
  const draco::Status st = enc.EncodeToBuffer(&res->buffer);
  if (!st.ok())
    return fail(err, cap, BT_DRACO_ERR_ENCODE, std::string("Draco encode failed: ") + st.error_msg());
  if (res->buffer.size() == 0)
    return fail(err, cap, BT_DRACO_ERR_ENCODE, "Draco produced an empty buffer");
  res->unique_ids.resize(num_attrs);
  for (uint32_t i = 0; i < num_attrs; ++i)
    res->unique_ids[i] = mesh.attribute(att_ids[i])->unique_id();
  res->num_points = enc.num_encoded_points();
  res->num_faces = enc.num_encoded_faces();
  *out = res.release();
  return BT_DRACO_OK;
}

int32_t decode_impl(const uint8_t *data, uint64_t len, bt_draco_mesh **out, char *err,
                    size_t cap) {
  if (data == nullptr || len == 0)
    return fail(err, cap, BT_DRACO_ERR_INVALID_ARGUMENT, "empty input");
  draco::DecoderBuffer buf;
  buf.Init(reinterpret_cast<const char *>(data), static_cast<size_t>(len));
  auto type = draco::Decoder::GetEncodedGeometryType(&buf);
  if (!type.ok())
    return fail(err, cap, BT_DRACO_ERR_DECODE,
                std::string("not a Draco bitstream: ") + type.status().error_msg());
  if (type.value() != draco::TRIANGULAR_MESH)
    return fail(err, cap, BT_DRACO_ERR_UNSUPPORTED, "Draco bitstream is not a triangle mesh");
  draco::Decoder dec;
  auto res = dec.DecodeMeshFromBuffer(&buf);
  if (!res.ok())
    return fail(err, cap, BT_DRACO_ERR_DECODE,
                std::string("Draco decode failed: ") + res.status().error_msg());
  std::unique_ptr<draco::Mesh> mesh = std::move(res).value();
  if (!mesh) return fail(err, cap, BT_DRACO_ERR_DECODE, "Draco returned no mesh");

  // Validate everything the copy functions will touch, so they cannot read
  // out of bounds on a malformed (but "successfully decoded") stream.
  const uint64_t np = mesh->num_points();
  for (draco::FaceIndex f(0); f < mesh->num_faces(); ++f) {
    const auto &face = mesh->face(f);
    for (int c = 0; c < 3; ++c)
      if (face[c].value() >= np)
        return fail(err, cap, BT_DRACO_ERR_DECODE, "decoded face index out of range");
  }
  for (int32_t i = 0; i < mesh->num_attributes(); ++i) {
    const draco::PointAttribute *pa = mesh->attribute(i);
    if (pa == nullptr || pa->buffer() == nullptr)
      return fail(err, cap, BT_DRACO_ERR_DECODE, "decoded attribute has no data");
    if (draco_to_out_dtype(pa->data_type()) < 0)
      return fail(err, cap, BT_DRACO_ERR_UNSUPPORTED,
                  "decoded attribute has an unsupported data type (64-bit integer?)");
    if (pa->num_components() < 1 || pa->num_components() > 4)
      return fail(err, cap, BT_DRACO_ERR_UNSUPPORTED, "decoded attribute has >4 components");
    const int64_t min_stride =
        static_cast<int64_t>(pa->num_components()) * draco::DataTypeLength(pa->data_type());
    if (min_stride <= 0 || pa->byte_stride() < min_stride || pa->byte_offset() != 0)
      return fail(err, cap, BT_DRACO_ERR_DECODE, "decoded attribute has a bad layout");
    const uint64_t need =
        static_cast<uint64_t>(pa->size()) * static_cast<uint64_t>(pa->byte_stride());
    if (static_cast<uint64_t>(pa->buffer()->data_size()) < need)
      return fail(err, cap, BT_DRACO_ERR_DECODE, "decoded attribute buffer is too small");
    if (!pa->is_mapping_identity() && pa->indices_map_size() < np)
      return fail(err, cap, BT_DRACO_ERR_DECODE, "decoded attribute map is too small");
    for (draco::PointIndex p(0); p < static_cast<uint32_t>(np); ++p)
      if (pa->mapped_index(p).value() >= pa->size())
        return fail(err, cap, BT_DRACO_ERR_DECODE, "decoded attribute index out of range");
  }
  std::unique_ptr<bt_draco_mesh> h(new bt_draco_mesh());
  h->mesh = std::move(mesh);
  *out = h.release();
  return BT_DRACO_OK;
}

template <typename T>
int32_t copy_attr(const draco::PointAttribute *pa, uint32_t np, void *out) {
  const int nc = pa->num_components();
  T *dst = static_cast<T *>(out);
  const size_t row = sizeof(T) * nc;
  draco::DataType native;
  size_t native_size = 0;
  if (dtype_to_draco(draco_to_out_dtype(pa->data_type()), &native, &native_size) &&
      native == pa->data_type() && native_size == sizeof(T)) {
    // Same representation: plain copy of each point's value.
    for (draco::PointIndex p(0); p < np; ++p)
      std::memcpy(dst + static_cast<size_t>(p.value()) * nc, pa->GetAddress(pa->mapped_index(p)),
                  row);
    return BT_DRACO_OK;
  }
  for (draco::PointIndex p(0); p < np; ++p)
    if (!pa->ConvertValue<T>(pa->mapped_index(p), static_cast<int8_t>(nc),
                             dst + static_cast<size_t>(p.value()) * nc))
      return BT_DRACO_ERR_DECODE;
  return BT_DRACO_OK;
}

}  // namespace

extern "C" {

int32_t bt_draco_encode(const bt_draco_attribute *attrs, uint32_t num_attrs, uint64_t num_points,
                        const uint32_t *indices, uint64_t num_indices,
                        const bt_draco_encode_options *opts, bt_draco_encoded **out, char *err,
                        size_t err_cap) {
  if (out == nullptr) return fail(err, err_cap, BT_DRACO_ERR_INVALID_ARGUMENT, "out is NULL");
  *out = nullptr;
  try {
    return encode_impl(attrs, num_attrs, num_points, indices, num_indices, opts, out, err, err_cap);
  } catch (const std::bad_alloc &) {
    return fail(err, err_cap, BT_DRACO_ERR_OUT_OF_MEMORY, "out of memory while encoding");
  } catch (const std::exception &e) {
    return fail(err, err_cap, BT_DRACO_ERR_INTERNAL, std::string("exception: ") + e.what());
  } catch (...) {
    return fail(err, err_cap, BT_DRACO_ERR_INTERNAL, "unknown exception while encoding");
  }
}

const uint8_t *bt_draco_encoded_data(const bt_draco_encoded *e) {
  return e ? reinterpret_cast<const uint8_t *>(e->buffer.data()) : nullptr;
}
uint64_t bt_draco_encoded_size(const bt_draco_encoded *e) { return e ? e->buffer.size() : 0; }
uint32_t bt_draco_encoded_unique_id(const bt_draco_encoded *e, uint32_t i) {
  if (e == nullptr || i >= e->unique_ids.size()) return UINT32_MAX;
  return e->unique_ids[i];
}
uint64_t bt_draco_encoded_num_points(const bt_draco_encoded *e) { return e ? e->num_points : 0; }
uint64_t bt_draco_encoded_num_faces(const bt_draco_encoded *e) { return e ? e->num_faces : 0; }
void bt_draco_encoded_free(bt_draco_encoded *e) { delete e; }

int32_t bt_draco_decode(const uint8_t *data, uint64_t len, bt_draco_mesh **out, char *err,
                        size_t err_cap) {
  if (out == nullptr) return fail(err, err_cap, BT_DRACO_ERR_INVALID_ARGUMENT, "out is NULL");
  *out = nullptr;
  try {
    return decode_impl(data, len, out, err, err_cap);
  } catch (const std::bad_alloc &) {
    return fail(err, err_cap, BT_DRACO_ERR_OUT_OF_MEMORY, "out of memory while decoding");
  } catch (const std::exception &e) {
    return fail(err, err_cap, BT_DRACO_ERR_INTERNAL, std::string("exception: ") + e.what());
  } catch (...) {
    return fail(err, err_cap, BT_DRACO_ERR_INTERNAL, "unknown exception while decoding");
  }
}

uint64_t bt_draco_mesh_num_points(const bt_draco_mesh *m) {
  return (m && m->mesh) ? m->mesh->num_points() : 0;
}
uint64_t bt_draco_mesh_num_faces(const bt_draco_mesh *m) {
  return (m && m->mesh) ? m->mesh->num_faces() : 0;
}
uint32_t bt_draco_mesh_num_attributes(const bt_draco_mesh *m) {
  return (m && m->mesh) ? static_cast<uint32_t>(m->mesh->num_attributes()) : 0;
}

int32_t bt_draco_mesh_attribute_info(const bt_draco_mesh *m, uint32_t i,
                                     bt_draco_attribute_info *out) {
  if (m == nullptr || !m->mesh || out == nullptr ||
      i >= static_cast<uint32_t>(m->mesh->num_attributes()))
    return BT_DRACO_ERR_INVALID_ARGUMENT;
  const draco::PointAttribute *pa = m->mesh->attribute(static_cast<int32_t>(i));
  out->unique_id = pa->unique_id();
  out->kind = static_cast<int32_t>(pa->attribute_type());
  out->dtype = draco_to_out_dtype(pa->data_type());
  out->components = pa->num_components();
  out->normalized = pa->normalized() ? 1 : 0;
  return BT_DRACO_OK;
}

int32_t bt_draco_mesh_copy_indices(const bt_draco_mesh *m, uint32_t *out, uint64_t cap) {
  if (m == nullptr || !m->mesh || (out == nullptr && m->mesh->num_faces() > 0))
    return BT_DRACO_ERR_INVALID_ARGUMENT;
  const uint64_t nf = m->mesh->num_faces();
  if (cap < nf * 3) return BT_DRACO_ERR_INVALID_ARGUMENT;
  for (draco::FaceIndex f(0); f < m->mesh->num_faces(); ++f) {
    const auto &face = m->mesh->face(f);
    for (int c = 0; c < 3; ++c) out[3 * static_cast<size_t>(f.value()) + c] = face[c].value();
  }
  return BT_DRACO_OK;
}

int32_t bt_draco_mesh_copy_attribute(const bt_draco_mesh *m, uint32_t i, void *out,
                                     uint64_t cap_bytes) {
  try {
    if (m == nullptr || !m->mesh || i >= static_cast<uint32_t>(m->mesh->num_attributes()))
      return BT_DRACO_ERR_INVALID_ARGUMENT;
    const draco::PointAttribute *pa = m->mesh->attribute(static_cast<int32_t>(i));
    const int32_t dt = draco_to_out_dtype(pa->data_type());
    if (dt < 0) return BT_DRACO_ERR_UNSUPPORTED;
    const uint32_t np = m->mesh->num_points();
    const uint64_t need = static_cast<uint64_t>(np) * pa->num_components() * out_dtype_size(dt);
    if (cap_bytes < need || (out == nullptr && need > 0)) return BT_DRACO_ERR_INVALID_ARGUMENT;
    switch (dt) {
      case BT_DRACO_DTYPE_F32: return copy_attr<float>(pa, np, out);
      case BT_DRACO_DTYPE_U8: return copy_attr<uint8_t>(pa, np, out);
      case BT_DRACO_DTYPE_U16: return copy_attr<uint16_t>(pa, np, out);
      case BT_DRACO_DTYPE_U32: return copy_attr<uint32_t>(pa, np, out);
      case BT_DRACO_DTYPE_I8: return copy_attr<int8_t>(pa, np, out);
      case BT_DRACO_DTYPE_I16: return copy_attr<int16_t>(pa, np, out);
      case BT_DRACO_DTYPE_I32: return copy_attr<int32_t>(pa, np, out);
      default: return BT_DRACO_ERR_UNSUPPORTED;
    }
  } catch (...) {
    return BT_DRACO_ERR_INTERNAL;
  }
}

void bt_draco_mesh_free(bt_draco_mesh *m) { delete m; }

}  // extern "C"
