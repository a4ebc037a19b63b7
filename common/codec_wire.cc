// encode<T> / decode<T> (declared in common/bus.h): LCM bytes with their
// fingerprint to and from the plain structs, through the conversions of codec.h.
#include <climits>
#include <cstdint>
#include <exception>
#include <stdexcept>
#include <string>
#include <vector>

#include <radslam/control_t.hpp>
#include <radslam/field_update_t.hpp>
#include <radslam/frame_t.hpp>
#include <radslam/keyframe_t.hpp>
#include <radslam/objects_t.hpp>
#include <radslam/pose_stamped_t.hpp>
#include <radslam/render_request_t.hpp>
#include <radslam/render_t.hpp>
#include <radslam/status_t.hpp>

#include "common/bus.h"
#include "common/codec.h"

namespace radslam {

namespace {

template <class T>
struct LcmTypeOf;
template <>
struct LcmTypeOf<Frame> {
  using type = frame_t;
};
template <>
struct LcmTypeOf<PoseStamped> {
  using type = pose_stamped_t;
};
template <>
struct LcmTypeOf<Keyframe> {
  using type = keyframe_t;
};
template <>
struct LcmTypeOf<ObjectList> {
  using type = objects_t;
};
template <>
struct LcmTypeOf<FieldUpdate> {
  using type = field_update_t;
};
template <>
struct LcmTypeOf<RenderRequest> {
  using type = render_request_t;
};
template <>
struct LcmTypeOf<RenderResult> {
  using type = render_t;
};
template <>
struct LcmTypeOf<Status> {
  using type = status_t;
};
template <>
struct LcmTypeOf<Control> {
  using type = control_t;
};

template <class L>
std::string lcmTypeName() {
  return std::string("radslam.") + L::getTypeName();
}

}  // namespace

template <class T>
std::vector<uint8_t> encode(const T& msg) {
  using L = typename LcmTypeOf<T>::type;
  L lcm_msg;
  codec::toLcm(msg, &lcm_msg);
  // getEncodedSize() is an int: guard against messages past 2 GiB.
  const int size = lcm_msg.getEncodedSize();
  if (size <= 0) throw std::invalid_argument(lcmTypeName<L>() + ": message too large to encode");
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  if (lcm_msg.encode(bytes.data(), 0, size) != size) {
    throw std::runtime_error(lcmTypeName<L>() + ": LCM encoding failed");
  }
  return bytes;
}

template <class T>
bool decode(const uint8_t* data, size_t size, T* msg, std::string* error) {
  using L = typename LcmTypeOf<T>::type;
  std::string local_error;
  if (!error) error = &local_error;
  const std::string type = lcmTypeName<L>();
  try {
    if (!msg) {
      *error = "decode<" + type + ">: no output message";
      return false;
    }
    if (size < 8 || !data) {
      *error = "truncated " + type + " (" + std::to_string(size) + " bytes, fingerprint needs 8)";
      return false;
    }
    if (size > static_cast<size_t>(INT_MAX)) {
      *error = type + " of " + std::to_string(size) + " bytes exceeds 2 GiB";
      return false;
    }
    uint64_t fingerprint = 0;
    for (int i = 0; i < 8; ++i) fingerprint = (fingerprint << 8) | data[i];  // big endian
    if (static_cast<int64_t>(fingerprint) != L::getHash()) {
      *error = "message is not a " + type + " (fingerprint mismatch)";
      return false;
    }
    // The generated decoders (patched at build time) reject array and string
    // lengths beyond the bytes left before allocating.
    L lcm_msg;
    const int used = lcm_msg.decode(data, 0, static_cast<int>(size));
    if (used < 0) {
      *error = "malformed " + type + " (" + std::to_string(size) +
               " bytes): truncated, or an array or string length exceeds the bytes left";
      return false;
    }
    if (static_cast<size_t>(used) != size) {
      *error = "malformed " + type + ": " + std::to_string(size - static_cast<size_t>(used)) +
               " bytes after the end of the message";
      return false;
    }
    T out;
    std::string field_error;
    if (!codec::fromLcm(lcm_msg, &out, &field_error)) {
      *error = "invalid " + type + ": " + field_error;
      return false;
    }
    *msg = std::move(out);
    return true;
  } catch (const std::length_error& e) {
    // A string length of 0 or less makes the generated decoder throw this.
    *error = "malformed " + type + " (" + std::to_string(size) +
             " bytes): a string length field is 0 or negative (" + e.what() + ")";
  } catch (const std::exception& e) {
    *error = "malformed " + type + ": " + e.what();
  } catch (...) {
    *error = "malformed " + type + ": unknown exception while decoding";
  }
  return false;
}

#define RADSLAM_INSTANTIATE_CODEC(T)                 \
  template std::vector<uint8_t> encode<T>(const T&); \
  template bool decode<T>(const uint8_t*, size_t, T*, std::string*);

RADSLAM_INSTANTIATE_CODEC(Frame)
RADSLAM_INSTANTIATE_CODEC(PoseStamped)
RADSLAM_INSTANTIATE_CODEC(Keyframe)
RADSLAM_INSTANTIATE_CODEC(ObjectList)
RADSLAM_INSTANTIATE_CODEC(FieldUpdate)
RADSLAM_INSTANTIATE_CODEC(RenderRequest)
RADSLAM_INSTANTIATE_CODEC(RenderResult)
RADSLAM_INSTANTIATE_CODEC(Status)
RADSLAM_INSTANTIATE_CODEC(Control)

#undef RADSLAM_INSTANTIATE_CODEC

}  // namespace radslam
