// Bus over lcm::LCM: typed publish/subscribe through the codec, raw access for
// the recorder, drop accounting with rate-limited warnings.
#include "common/bus.h"

#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <map>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <lcm/lcm-cpp.hpp>

namespace radslam {
namespace {

// Warn on the first kWarnFirst bad messages of a channel, then every kWarnEvery-th.
constexpr int64_t kWarnFirst = 5;
constexpr int64_t kWarnEvery = 100;
// Messages dispatched by one handle() call after the first, so a busy channel
// cannot keep handle() from returning.
constexpr int kMaxBatch = 1000;
// Messages a raw subscription may queue while its handler is busy (LCM's default is 30).
constexpr int kRawQueueCapacity = 5000;

// LCM treats subscription channels as regular expressions (anchored ^...$);
// typed subscriptions and the prefix must match literally.
std::string escapeRegex(const std::string& text) {
  std::string out;
  out.reserve(text.size() * 2);
  for (char c : text) {
    const bool plain =
        (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_';
    if (!plain) out += '\\';
    out += c;
  }
  return out;
}

// Fault injection for tests of lost messages: RADSLAM_DROP="KEYFRAME=0.05,FIELD=0.05" drops
// that fraction of the messages this process publishes on those channels (names without the
// prefix), evenly spread (with 0.05, the 10th, 30th, ... message) so that a test run is
// reproducible. A dropped message still takes its sequence number, as one lost on the network.
std::map<std::string, double> dropRatesFromEnvironment(const std::string& sender) {
  std::map<std::string, double> rates;
  const char* spec = std::getenv("RADSLAM_DROP");
  if (!spec || !*spec) return rates;
  std::stringstream items(spec);
  std::string item;
  while (std::getline(items, item, ',')) {
    const size_t eq = item.find('=');
    char* end = nullptr;
    const double p = eq == std::string::npos ? -1 : std::strtod(item.c_str() + eq + 1, &end);
    if (eq == std::string::npos || eq == 0 || !end || *end || !(p >= 0 && p <= 1))
      throw std::runtime_error("RADSLAM_DROP: '" + item + "' is not CHANNEL=FRACTION (0 to 1)");
    rates[item.substr(0, eq)] = p;
  }
  for (const auto& [channel, p] : rates)
    std::fprintf(stderr, "%s: fault injection: dropping %.1f%% of the %s messages it publishes\n",
                 sender.c_str(), 100 * p, channel.c_str());
  return rates;
}

}  // namespace

struct Bus::Impl {
  struct Subscriber {
    explicit Subscriber(Impl* owner) : impl(owner) {}
    virtual ~Subscriber() = default;
    virtual void onMessage(const lcm::ReceiveBuffer* rbuf, const std::string& channel) = 0;
    Impl* impl;
  };

  template <class T>
  struct TypedSubscriber : Subscriber {
    TypedSubscriber(Impl* owner, std::function<void(const T&)> h)
        : Subscriber(owner), handler(std::move(h)) {}
    void onMessage(const lcm::ReceiveBuffer* rbuf, const std::string& channel) override {
      T msg;
      std::string error;
      if (!decode(static_cast<const uint8_t*>(rbuf->data), rbuf->data_size, &msg, &error)) {
        impl->reportDrop(channel, error);
        return;
      }
      impl->run([&] { handler(msg); });
    }
    std::function<void(const T&)> handler;
  };

  struct RawSubscriber : Subscriber {
    RawSubscriber(Impl* owner, RawHandler h) : Subscriber(owner), handler(std::move(h)) {}
    void onMessage(const lcm::ReceiveBuffer* rbuf, const std::string& channel) override {
      impl->run([&] {
        handler(channel, rbuf->recv_utime, static_cast<const uint8_t*>(rbuf->data),
                rbuf->data_size);
      });
    }
    RawHandler handler;
  };

  Impl(const std::string& url, std::string sender_name)
      : lcm(url), sender(std::move(sender_name)) {}

  // Handlers run inside LCM's C dispatch loop: an exception must not unwind
  // through it, so the first one is kept and rethrown by handle().
  template <class F>
  void run(F&& f) {
    try {
      f();
    } catch (...) {
      if (!handler_error) handler_error = std::current_exception();
    }
  }

  void reportDrop(const std::string& channel, const std::string& error) {
    dropped.fetch_add(1);
    int64_t n;
    {
      std::lock_guard<std::mutex> lock(mutex);
      n = ++drops_per_channel[channel];
    }
    if (n <= kWarnFirst || n % kWarnEvery == 0) {
      std::fprintf(stderr,
                   "%s: warning: channel %s: %s (message skipped; %lld on this channel%s)\n",
                   sender.c_str(), channel.c_str(), error.c_str(), static_cast<long long>(n),
                   n == kWarnFirst ? ", now warning every 100th" : "");
    }
  }

  // True when fault injection drops this message of `channel` (the name without prefix): the
  // n-th message is dropped when round(n p) grows (with p = 0.05: the 10th, 30th, ...).
  bool injectDrop(const std::string& channel) {
    if (drop_rates.empty()) return false;
    const auto it = drop_rates.find(channel);
    if (it == drop_rates.end()) return false;
    std::lock_guard<std::mutex> lock(mutex);
    const int64_t n = ++drop_counts[channel];
    const double p = it->second;
    const bool drop = std::floor(n * p + 0.5) > std::floor((n - 1) * p + 0.5);
    if (drop) {
      const int64_t k = ++dropped_injected[channel];
      if (k <= kWarnFirst || k % kWarnEvery == 0)
        std::fprintf(stderr, "%s: fault injection: dropped %s message %lld (%lld so far)\n",
                     sender.c_str(), channel.c_str(), static_cast<long long>(n),
                     static_cast<long long>(k));
    }
    return drop;
  }

  bool publishBytes(const std::string& channel, const uint8_t* data, size_t size) {
    if (size > static_cast<size_t>(INT32_MAX) ||
        lcm.publish(channel, data, static_cast<unsigned int>(size)) != 0) {
      std::fprintf(stderr, "%s: warning: channel %s: LCM refused a message of %zu bytes\n",
                   sender.c_str(), channel.c_str(), size);
      return false;
    }
    return true;
  }

  int64_t nextSeq(const std::string& channel) {
    std::lock_guard<std::mutex> lock(mutex);
    return seq[channel]++;
  }

  // Destroyed in reverse order: lcm (and its subscriptions) before the handlers.
  std::vector<std::unique_ptr<Subscriber>> subscribers;
  lcm::LCM lcm;
  std::string sender;
  std::mutex mutex;  // seq, drops_per_channel (publish may run on other threads)
  std::map<std::string, int64_t> seq;
  std::map<std::string, int64_t> drops_per_channel;
  std::atomic<int64_t> dropped{0};
  std::exception_ptr handler_error;
  std::map<std::string, double> drop_rates;  // fault injection (RADSLAM_DROP)
  std::map<std::string, int64_t> drop_counts, dropped_injected;
};

Bus::Bus(const std::string& url, const std::string& prefix, const std::string& sender)
    : impl_(std::make_unique<Impl>(url, sender)), prefix_(prefix) {
  if (!impl_->lcm.good()) throw std::runtime_error("cannot open LCM URL '" + url + "'");
  impl_->drop_rates = dropRatesFromEnvironment(sender);
}

Bus::~Bus() = default;

template <class T>
bool Bus::publish(const std::string& channel, T msg) {
  const std::string full = fullChannel(channel);
  msg.header.sender = impl_->sender;
  msg.header.seq = impl_->nextSeq(full);
  const std::vector<uint8_t> bytes = encode(msg);
  if (impl_->injectDrop(channel)) return true;  // "sent", lost on the way
  return impl_->publishBytes(full, bytes.data(), bytes.size());
}

template <class T>
void Bus::subscribe(const std::string& channel, std::function<void(const T&)> handler) {
  auto sub = std::make_unique<Impl::TypedSubscriber<T>>(impl_.get(), std::move(handler));
  impl_->lcm.subscribe(escapeRegex(fullChannel(channel)), &Impl::Subscriber::onMessage,
                       static_cast<Impl::Subscriber*>(sub.get()));
  impl_->subscribers.push_back(std::move(sub));
}

void Bus::subscribeRaw(const std::string& channel_regex, RawHandler handler) {
  auto sub = std::make_unique<Impl::RawSubscriber>(impl_.get(), std::move(handler));
  lcm::Subscription* subscription =
      impl_->lcm.subscribe(escapeRegex(prefix_) + "(" + channel_regex + ")",
                           &Impl::Subscriber::onMessage, static_cast<Impl::Subscriber*>(sub.get()));
  // LCM drops beyond 30 queued messages per subscription; a raw subscriber (the recorder)
  // must keep every message of a burst (e.g. the tracker's final poses behind keyframes).
  if (subscription) subscription->setQueueCapacity(kRawQueueCapacity);
  impl_->subscribers.push_back(std::move(sub));
}

bool Bus::publishRaw(const std::string& full_channel, const uint8_t* data, size_t size) {
  return impl_->publishBytes(full_channel, data, size);
}

int Bus::handle(int timeout_ms) {
  int first;
  if (timeout_ms < 0) {
    first = impl_->lcm.handle() == 0 ? 1 : -1;
  } else {
    errno = 0;
    first = impl_->lcm.handleTimeout(timeout_ms);
    // A signal (Ctrl-C, SIGTERM) interrupting the wait is not a bus error.
    if (first < 0 && errno == EINTR) first = 0;
  }
  int handled = first > 0 ? 1 : 0;
  while (first > 0 && !impl_->handler_error && handled < kMaxBatch &&
         impl_->lcm.handleTimeout(0) > 0) {
    ++handled;
  }
  if (impl_->handler_error) std::rethrow_exception(std::exchange(impl_->handler_error, nullptr));
  return first < 0 ? -1 : handled;
}

int64_t Bus::droppedMessages() const { return impl_->dropped.load(); }

#define RADSLAM_INSTANTIATE_BUS(T)                      \
  template bool Bus::publish<T>(const std::string&, T); \
  template void Bus::subscribe<T>(const std::string&, std::function<void(const T&)>);

RADSLAM_INSTANTIATE_BUS(Frame)
RADSLAM_INSTANTIATE_BUS(PoseStamped)
RADSLAM_INSTANTIATE_BUS(Keyframe)
RADSLAM_INSTANTIATE_BUS(ObjectList)
RADSLAM_INSTANTIATE_BUS(FieldUpdate)
RADSLAM_INSTANTIATE_BUS(RenderRequest)
RADSLAM_INSTANTIATE_BUS(RenderResult)
RADSLAM_INSTANTIATE_BUS(Status)
RADSLAM_INSTANTIATE_BUS(Control)

#undef RADSLAM_INSTANTIATE_BUS

}  // namespace radslam
