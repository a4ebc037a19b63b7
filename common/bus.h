// The bus adapter: the only code in radslam that knows LCM. Core classes
// exchange the plain structs of common/types.h; Bus moves them over an LCM URL
// (memq://, udpm://..., file://...) under a configurable channel prefix.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "common/types.h"

namespace radslam {

/// Channel base names (the bus prepends its prefix).
namespace channel {
inline constexpr const char* kCamera = "CAMERA";
inline constexpr const char* kGroundTruth = "GROUND_TRUTH";
inline constexpr const char* kGroundTruthObjects = "GROUND_TRUTH_OBJECTS";
inline constexpr const char* kPose = "POSE";
inline constexpr const char* kKeyframe = "KEYFRAME";
inline constexpr const char* kObjects = "OBJECTS";
inline constexpr const char* kField = "FIELD";
inline constexpr const char* kRenderRequest = "RENDER_REQUEST";
inline constexpr const char* kRender = "RENDER";
inline constexpr const char* kStatus = "STATUS";
inline constexpr const char* kControl = "CONTROL";
}  // namespace channel

/// Encodes a message to LCM bytes (with fingerprint) / decodes it back.
/// Implemented for Frame, PoseStamped, Keyframe, ObjectList, FieldUpdate,
/// RenderRequest, RenderResult, Status and Control (common/codec*.cc).
/// encode() throws std::invalid_argument for content it cannot carry
/// (unsupported image type, images of one message differing in size).
/// decode() never throws: it returns false and fills *error (when error is not
/// null) with what is wrong (wrong type, truncated, absurd size, enum out of
/// range, non-finite pose, undecodable image), checking sizes before allocating.
/// Colour images travel as RGB and come back BGR; see Frame for the depth and
/// compression hints, which decode() sets from what was received.
template <class T>
std::vector<uint8_t> encode(const T& msg);
template <class T>
bool decode(const uint8_t* data, size_t size, T* msg, std::string* error);

class Bus {
 public:
  /// url: an LCM provider URL ("" = LCM's default). prefix is prepended to
  /// every channel name. sender is written into every header published.
  /// Throws std::runtime_error when the URL cannot be opened.
  Bus(const std::string& url, const std::string& prefix, const std::string& sender);
  ~Bus();
  Bus(const Bus&) = delete;
  Bus& operator=(const Bus&) = delete;

  /// Fills header.sender and header.seq (per channel, from 0) and publishes on
  /// prefix + channel. Returns false (with a warning on stderr) when LCM refuses
  /// the message; throws std::invalid_argument when msg cannot be encoded
  /// (unsupported image type, inconsistent image sizes).
  template <class T>
  bool publish(const std::string& channel, T msg);

  /// Calls handler for each well-formed message of type T on prefix + channel
  /// (an exact name, not a regex); malformed ones are skipped with a warning on
  /// stderr naming the channel (the first 5 per channel, then every 100th) and
  /// counted in droppedMessages(). An exception thrown by handler propagates out
  /// of handle().
  template <class T>
  void subscribe(const std::string& channel, std::function<void(const T&)> handler);

  /// Raw access (recorder): every channel matching the regex (prefix applied),
  /// with the full channel name, receive time (us) and the undecoded bytes. Its queue
  /// holds up to 5000 messages (typed subscriptions: LCM's 30), so a burst is not dropped.
  using RawHandler = std::function<void(const std::string& channel, int64_t recv_utime,
                                        const uint8_t* data, size_t size)>;
  void subscribeRaw(const std::string& channel_regex, RawHandler handler);
  /// Publishes bytes as they are on full_channel (no prefix added). Returns
  /// false (with a warning) when LCM refuses them.
  bool publishRaw(const std::string& full_channel, const uint8_t* data, size_t size);

  /// Waits at most timeout_ms (0 = poll, < 0 = forever) for a message, then
  /// also dispatches the messages already queued (up to 1000). Returns the
  /// number of messages handled (0 on timeout), -1 on error (e.g. the end of a
  /// file:// log). Rethrows the first exception a handler threw.
  int handle(int timeout_ms);

  const std::string& prefix() const { return prefix_; }
  std::string fullChannel(const std::string& channel) const { return prefix_ + channel; }
  /// Number of messages skipped because they could not be decoded.
  int64_t droppedMessages() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string prefix_;
};

}  // namespace radslam
