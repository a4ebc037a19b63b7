// Building blocks of the codec: images, poses, cameras and headers between
// OpenCV/Eigen and the lcm-gen types. Messages are assembled in codec.cc.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <radslam/camera_t.hpp>
#include <radslam/header_t.hpp>
#include <radslam/image_t.hpp>
#include <radslam/pose_t.hpp>

#include "common/camera.h"
#include "common/codec.h"

namespace radslam {
namespace codec {
namespace {

constexpr int kPngLevel = 1;      // zlib level: fast, still ~2-4x on depth and masks
constexpr int kJpegQuality = 95;  // visually lossless for tracking and display
// Deflate (PNG) expands at most 1032:1; sequential JPEG, as radslam sends it,
// needs at least 2 bits per 8x8 block and channel, a smaller ratio. A compressed
// image declaring more pixels than its bytes can hold is corrupt or hostile and
// is refused before OpenCV allocates the declared size.
constexpr int64_t kMaxInflationRatio = 1032;
// Below this many decoded bytes the ratio is not checked (headers dominate).
constexpr int64_t kMinInflationCheckBytes = 1 << 20;
// OpenCV supports 4, 5, 8, 12 or 14 distortion coefficients.
constexpr int kMaxDistortion = 14;

bool fail(std::string* error, const std::string& message) {
  *error = message;
  return false;
}

int bytesPerPixel(int8_t format) {
  switch (format) {
    case image_t::GREY8:
      return 1;
    case image_t::RGB8:
      return 3;
    case image_t::UINT16:
      return 2;
    case image_t::FLOAT32:
      return 4;
    default:
      return 0;
  }
}

const char* formatName(int8_t format) {
  switch (format) {
    case image_t::GREY8:
      return "GREY8";
    case image_t::RGB8:
      return "RGB8";
    case image_t::UINT16:
      return "UINT16";
    case image_t::FLOAT32:
      return "FLOAT32";
    default:
      return "?";
  }
}

int cvTypeOf(int8_t format) {
  switch (format) {
    case image_t::GREY8:
      return CV_8UC1;
    case image_t::RGB8:
      return CV_8UC3;
    case image_t::UINT16:
      return CV_16UC1;
    default:
      return CV_32FC1;
  }
}

std::string allowedNames(int mask) {
  std::string names;
  for (int8_t f = image_t::GREY8; f <= image_t::FLOAT32; ++f) {
    if (!(mask & (1 << f))) continue;
    if (!names.empty()) names += " or ";
    names += formatName(f);
  }
  return names;
}

// Multi-byte pixels travel little endian (image_t), whatever the host order.
std::vector<uint8_t> rawBytes(const cv::Mat& image, int8_t format) {
  const int bpp = bytesPerPixel(format);
  const size_t row_bytes = static_cast<size_t>(image.cols) * static_cast<size_t>(bpp);
  std::vector<uint8_t> out(row_bytes * static_cast<size_t>(image.rows));
  for (int r = 0; r < image.rows; ++r) {
    uint8_t* dst = out.data() + row_bytes * static_cast<size_t>(r);
    switch (format) {
      case image_t::GREY8:
        std::memcpy(dst, image.ptr<uint8_t>(r), row_bytes);
        break;
      case image_t::RGB8: {
        const uint8_t* src = image.ptr<uint8_t>(r);
        for (int x = 0; x < image.cols; ++x, src += 3, dst += 3) {
          dst[0] = src[2];
          dst[1] = src[1];
          dst[2] = src[0];
        }
        break;
      }
      case image_t::UINT16: {
        const uint16_t* src = image.ptr<uint16_t>(r);
        for (int x = 0; x < image.cols; ++x, dst += 2) {
          dst[0] = static_cast<uint8_t>(src[x] & 0xff);
          dst[1] = static_cast<uint8_t>(src[x] >> 8);
        }
        break;
      }
      case image_t::FLOAT32: {
        const float* src = image.ptr<float>(r);
        for (int x = 0; x < image.cols; ++x, dst += 4) {
          uint32_t bits;
          std::memcpy(&bits, &src[x], 4);
          for (int b = 0; b < 4; ++b) dst[b] = static_cast<uint8_t>(bits >> (8 * b));
        }
        break;
      }
      default:
        break;
    }
  }
  return out;
}

cv::Mat fromRawBytes(const uint8_t* data, int width, int height, int8_t format) {
  cv::Mat image(height, width, cvTypeOf(format));
  const int bpp = bytesPerPixel(format);
  const size_t row_bytes = static_cast<size_t>(width) * static_cast<size_t>(bpp);
  for (int r = 0; r < height; ++r) {
    const uint8_t* src = data + row_bytes * static_cast<size_t>(r);
    switch (format) {
      case image_t::GREY8:
        std::memcpy(image.ptr<uint8_t>(r), src, row_bytes);
        break;
      case image_t::RGB8: {
        uint8_t* dst = image.ptr<uint8_t>(r);
        for (int x = 0; x < width; ++x, src += 3, dst += 3) {
          dst[0] = src[2];
          dst[1] = src[1];
          dst[2] = src[0];
        }
        break;
      }
      case image_t::UINT16: {
        uint16_t* dst = image.ptr<uint16_t>(r);
        for (int x = 0; x < width; ++x, src += 2) {
          dst[x] = static_cast<uint16_t>(src[0] | (src[1] << 8));
        }
        break;
      }
      case image_t::FLOAT32: {
        float* dst = image.ptr<float>(r);
        for (int x = 0; x < width; ++x, src += 4) {
          const uint32_t bits =
              static_cast<uint32_t>(src[0]) | (static_cast<uint32_t>(src[1]) << 8) |
              (static_cast<uint32_t>(src[2]) << 16) | (static_cast<uint32_t>(src[3]) << 24);
          std::memcpy(&dst[x], &bits, 4);
        }
        break;
      }
      default:
        break;
    }
  }
  return image;
}

uint32_t readBigEndian32(const uint8_t* p) {
  return (static_cast<uint32_t>(p[0]) << 24) | (static_cast<uint32_t>(p[1]) << 16) |
         (static_cast<uint32_t>(p[2]) << 8) | static_cast<uint32_t>(p[3]);
}

// Image size from the PNG IHDR chunk, read before decoding so that a stream
// claiming more pixels than the message declares is never decompressed.
bool peekPngSize(const std::vector<uint8_t>& d, int64_t* width, int64_t* height) {
  static const uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (d.size() < 24 || std::memcmp(d.data(), kSignature, 8) != 0) return false;
  if (std::memcmp(d.data() + 12, "IHDR", 4) != 0) return false;
  *width = readBigEndian32(d.data() + 16);
  *height = readBigEndian32(d.data() + 20);
  return true;
}

// Image size from the JPEG frame header (SOFn), same purpose as peekPngSize.
bool peekJpegSize(const std::vector<uint8_t>& d, int64_t* width, int64_t* height) {
  const size_t n = d.size();
  if (n < 4 || d[0] != 0xFF || d[1] != 0xD8) return false;
  size_t pos = 2;
  while (pos + 4 <= n) {
    if (d[pos] != 0xFF) return false;
    const uint8_t marker = d[pos + 1];
    if (marker == 0xFF) {  // fill byte
      ++pos;
      continue;
    }
    if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD8)) {  // markers without length
      pos += 2;
      continue;
    }
    if (marker == 0xD9 || marker == 0xDA) return false;  // end or scan before any frame header
    const size_t length = (static_cast<size_t>(d[pos + 2]) << 8) | d[pos + 3];
    if (length < 2) return false;
    const bool sof =
        marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC;
    if (sof) {
      if (length < 7 || pos + 9 > n) return false;
      *height = (static_cast<int64_t>(d[pos + 5]) << 8) | d[pos + 6];
      *width = (static_cast<int64_t>(d[pos + 7]) << 8) | d[pos + 8];
      return true;
    }
    pos += 2 + length;
  }
  return false;
}

}  // namespace

void imageToLcm(const cv::Mat& image, WireCompression compression, float scale,
                const std::string& name, image_t* out) {
  out->scale = scale;
  out->data.clear();
  out->compression = image_t::RAW;
  if (image.empty()) {
    out->width = 0;
    out->height = 0;
    out->format = image_t::GREY8;
    out->size = 0;
    return;
  }
  if (image.dims != 2 || image.cols > kMaxImageSide || image.rows > kMaxImageSide) {
    throw std::invalid_argument(name + ": image of " + std::to_string(image.cols) + "x" +
                                std::to_string(image.rows) + " exceeds " +
                                std::to_string(kMaxImageSide) + " pixels per side");
  }
  switch (image.type()) {
    case CV_8UC1:
      out->format = image_t::GREY8;
      break;
    case CV_8UC3:
      out->format = image_t::RGB8;
      break;
    case CV_16UC1:
      out->format = image_t::UINT16;
      break;
    case CV_32FC1:
      out->format = image_t::FLOAT32;
      break;
    default:
      throw std::invalid_argument(name + ": cannot send a " + cv::typeToString(image.type()) +
                                  " image (expected CV_8UC3, CV_8UC1, CV_16UC1 or CV_32FC1)");
  }
  out->width = image.cols;
  out->height = image.rows;
  switch (compression) {
    case WireCompression::kRaw:
      out->data = rawBytes(image, out->format);
      break;
    case WireCompression::kPng:
      if (out->format == image_t::FLOAT32) {
        throw std::invalid_argument(name + ": PNG cannot carry a FLOAT32 image");
      }
      out->compression = image_t::PNG;
      // imencode takes BGR and writes a standard (RGB) PNG.
      if (!cv::imencode(".png", image, out->data, {cv::IMWRITE_PNG_COMPRESSION, kPngLevel})) {
        throw std::runtime_error(name + ": PNG encoding failed");
      }
      break;
    case WireCompression::kJpeg:
      if (out->format != image_t::GREY8 && out->format != image_t::RGB8) {
        throw std::invalid_argument(name + ": JPEG carries 8-bit images only, not " +
                                    formatName(out->format));
      }
      out->compression = image_t::JPEG;
      if (!cv::imencode(".jpg", image, out->data, {cv::IMWRITE_JPEG_QUALITY, kJpegQuality})) {
        throw std::runtime_error(name + ": JPEG encoding failed");
      }
      break;
    default:
      throw std::invalid_argument(name + ": unknown compression " +
                                  std::to_string(static_cast<int>(compression)));
  }
  if (out->data.size() > static_cast<size_t>(std::numeric_limits<int32_t>::max())) {
    throw std::invalid_argument(name + ": image payload over 2 GiB");
  }
  out->size = static_cast<int32_t>(out->data.size());
}

bool imageFromLcm(const image_t& in, const std::string& name, int allowed_formats, cv::Mat* out,
                  std::string* error) {
  const std::string size_text = std::to_string(in.width) + "x" + std::to_string(in.height);
  if (in.width < 0 || in.height < 0 || in.width > kMaxImageSide || in.height > kMaxImageSide) {
    return fail(error, name + ": image size " + size_text + " outside [0, " +
                           std::to_string(kMaxImageSide) + "] per side");
  }
  if (in.size < 0 || static_cast<size_t>(in.size) != in.data.size()) {
    return fail(error, name + ": size field " + std::to_string(in.size) + " does not match " +
                           std::to_string(in.data.size()) + " data bytes");
  }
  if (in.width == 0) {
    if (in.height != 0 || !in.data.empty()) {
      return fail(error, name + ": width 0 (no image) but height " + std::to_string(in.height) +
                             " and " + std::to_string(in.data.size()) + " data bytes");
    }
    *out = cv::Mat();
    return true;
  }
  if (in.height == 0) return fail(error, name + ": image size " + size_text + " has no rows");
  if (bytesPerPixel(in.format) == 0) {
    return fail(error, name + ": unknown pixel format " + std::to_string(in.format));
  }
  if (!(allowed_formats & (1 << in.format))) {
    return fail(error, name + ": pixel format " + formatName(in.format) + " not allowed here (" +
                           allowedNames(allowed_formats) + " expected)");
  }
  if (!std::isfinite(in.scale)) return fail(error, name + ": scale is not finite");

  const int64_t expected_raw =
      static_cast<int64_t>(in.width) * in.height * bytesPerPixel(in.format);
  switch (in.compression) {
    case image_t::RAW:
      if (static_cast<int64_t>(in.data.size()) != expected_raw) {
        return fail(error, name + ": RAW " + formatName(in.format) + " " + size_text + " needs " +
                               std::to_string(expected_raw) + " bytes, message has " +
                               std::to_string(in.data.size()));
      }
      *out = fromRawBytes(in.data.data(), in.width, in.height, in.format);
      return true;
    case image_t::PNG:
    case image_t::JPEG: {
      const bool png = in.compression == image_t::PNG;
      const char* codec_name = png ? "PNG" : "JPEG";
      if (in.format == image_t::FLOAT32 || (!png && in.format == image_t::UINT16)) {
        return fail(error, name + ": " + codec_name + " cannot carry " + formatName(in.format));
      }
      int64_t w = 0, h = 0;
      const bool header_ok = png ? peekPngSize(in.data, &w, &h) : peekJpegSize(in.data, &w, &h);
      if (!header_ok) return fail(error, name + ": data is not a valid " + codec_name + " stream");
      if (w != in.width || h != in.height) {
        return fail(error, name + ": " + codec_name + " header says " + std::to_string(w) + "x" +
                               std::to_string(h) + " but the message declares " + size_text);
      }
      const int64_t compressed = static_cast<int64_t>(in.data.size());
      if (expected_raw > kMinInflationCheckBytes &&
          expected_raw > kMaxInflationRatio * compressed) {
        return fail(error, name + ": " + codec_name + " of " + std::to_string(compressed) +
                               " bytes cannot hold a " + size_text + " " + formatName(in.format) +
                               " image (more than " + std::to_string(kMaxInflationRatio) +
                               ":1 expansion)");
      }
      cv::Mat decoded;
      try {
        decoded = cv::imdecode(cv::Mat(1, static_cast<int>(in.data.size()), CV_8UC1,
                                       const_cast<uint8_t*>(in.data.data())),
                               cv::IMREAD_UNCHANGED);
      } catch (const cv::Exception& e) {
        return fail(error, name + ": " + codec_name + " data does not decode (" + e.what() + ")");
      }
      if (decoded.empty()) return fail(error, name + ": " + codec_name + " data does not decode");
      if (decoded.cols != in.width || decoded.rows != in.height ||
          decoded.type() != cvTypeOf(in.format)) {
        return fail(error, name + ": " + codec_name + " data decodes to a " +
                               std::to_string(decoded.cols) + "x" + std::to_string(decoded.rows) +
                               " " + cv::typeToString(decoded.type()) + " image, expected " +
                               size_text + " " + formatName(in.format));
      }
      *out = decoded;
      return true;
    }
    default:
      return fail(error, name + ": unknown compression " + std::to_string(in.compression));
  }
}

cv::Mat quantizeDepth(const cv::Mat& depth_m, float scale) {
  CV_Assert(depth_m.type() == CV_32FC1 && scale > 0);
  cv::Mat units(depth_m.size(), CV_16UC1);
  const double inv_scale = 1.0 / static_cast<double>(scale);
  for (int r = 0; r < depth_m.rows; ++r) {
    const float* src = depth_m.ptr<float>(r);
    uint16_t* dst = units.ptr<uint16_t>(r);
    for (int x = 0; x < depth_m.cols; ++x) {
      const double u = std::round(static_cast<double>(src[x]) * inv_scale);
      // NaN fails every comparison and lands on 0 (invalid) as well.
      dst[x] = (src[x] > 0 && u <= 65535.0) ? static_cast<uint16_t>(u) : 0;
    }
  }
  return units;
}

void poseToLcm(const SE3& T, pose_t* out) {
  const Eigen::Quaterniond& q = T.quaternion();
  for (int i = 0; i < 3; ++i) out->position[i] = T.translation()[i];
  out->orientation[0] = q.w();
  out->orientation[1] = q.x();
  out->orientation[2] = q.y();
  out->orientation[3] = q.z();
}

bool poseFromLcm(const pose_t& in, const std::string& name, SE3* out, std::string* error) {
  for (double v : in.position) {
    if (!std::isfinite(v)) return fail(error, name + ": position is not finite");
  }
  for (double v : in.orientation) {
    if (!std::isfinite(v)) return fail(error, name + ": orientation is not finite");
  }
  const Eigen::Quaterniond q(in.orientation[0], in.orientation[1], in.orientation[2],
                             in.orientation[3]);
  const double norm = q.norm();
  if (std::abs(norm - 1.0) > kQuaternionNormTolerance) {
    return fail(error, name + ": quaternion norm " + std::to_string(norm) +
                           " is not 1 (w, x, y, z unit quaternion expected)");
  }
  *out = SE3(q, Vec3(in.position[0], in.position[1], in.position[2]));  // SO3 renormalises
  return true;
}

void cameraToLcm(const CameraModel& camera, camera_t* out) {
  out->width = camera.width;
  out->height = camera.height;
  out->model = static_cast<int8_t>(camera.type);
  out->fx = camera.fx;
  out->fy = camera.fy;
  out->cx = camera.cx;
  out->cy = camera.cy;
  out->distortion = camera.distortion;
  out->num_distortion = static_cast<int32_t>(camera.distortion.size());
  out->readout_s = camera.readout_s;
}

bool cameraFromLcm(const camera_t& in, const std::string& name, CameraModel* out,
                   std::string* error) {
  if (in.width < 0 || in.height < 0 || in.width > kMaxImageSide || in.height > kMaxImageSide) {
    return fail(error, name + ": size " + std::to_string(in.width) + "x" +
                           std::to_string(in.height) + " outside [0, " +
                           std::to_string(kMaxImageSide) + "] per side");
  }
  if (in.model < camera_t::PINHOLE || in.model > camera_t::EQUIDISTANT) {
    return fail(error, name + ": unknown camera model " + std::to_string(in.model) +
                           " (0 pinhole, 1 radtan, 2 equidistant)");
  }
  if (!std::isfinite(in.fx) || !std::isfinite(in.fy) || !std::isfinite(in.cx) ||
      !std::isfinite(in.cy)) {
    return fail(error, name + ": intrinsics are not finite");
  }
  if (!(in.readout_s >= 0 && in.readout_s < 1)) {
    return fail(error, name + ": rolling shutter readout " + std::to_string(in.readout_s) +
                           " s is not in [0, 1)");
  }
  if (in.num_distortion > kMaxDistortion) {
    return fail(error, name + ": " + std::to_string(in.num_distortion) +
                           " distortion coefficients (at most " + std::to_string(kMaxDistortion) +
                           ")");
  }
  for (double k : in.distortion) {
    if (!std::isfinite(k)) return fail(error, name + ": distortion is not finite");
  }
  CameraModel camera;
  camera.width = in.width;
  camera.height = in.height;
  camera.type = static_cast<CameraModel::Type>(in.model);
  camera.fx = in.fx;
  camera.fy = in.fy;
  camera.cx = in.cx;
  camera.cy = in.cy;
  camera.distortion = in.distortion;
  camera.readout_s = in.readout_s;
  // A camera with a size is one the receiver projects with: refuse here what
  // its Undistorter or tracker would throw on (focal lengths > 0, coefficient
  // counts of the model). Size 0x0 means "no camera".
  if (in.width != 0 || in.height != 0) {
    try {
      validateCamera(camera);
    } catch (const std::invalid_argument& e) {
      std::string what = e.what();
      if (what.rfind("camera: ", 0) == 0) what.erase(0, 8);
      return fail(error, name + ": " + what);
    }
  }
  *out = std::move(camera);
  return true;
}

void headerToLcm(const Header& header, header_t* out) {
  out->utime = header.utime;
  out->seq = header.seq;
  out->sender = header.sender;
}

void headerFromLcm(const header_t& in, Header* out) {
  out->utime = in.utime;
  out->seq = in.seq;
  out->sender = in.sender;
}

}  // namespace codec
}  // namespace radslam
