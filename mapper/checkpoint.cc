// Mapper checkpoints: one little-endian binary file.
//   "RSMAPCK\0", u32 format version
//   u8 initialised; geometry (u32 levels, f64 voxel sizes, i32 sh degree, f32 bias)
//   i64 field version; per level: u32 blocks, then per block i32 x 3 index, i64 version and
//   u8 changed flag, and the level's
//   parameters, Adam first and second moments (f32) and per-voxel step counts (i32)
//   i64 trainer steps, u64 random state
//   i64 keyframe arrivals, u32 keyframes, each: ids and header, received and refined poses,
//   covariance, camera, pose Adam state, exposure and its Adam state (format 2), statistics,
//   then its images (may be empty)
// Written to PATH.tmp and renamed, so a crash never leaves a half-written checkpoint.
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>

#include "mapper/mapper.h"

namespace radslam {

namespace {

constexpr char kMagic[8] = {'R', 'S', 'M', 'A', 'P', 'C', 'K', '\0'};
constexpr uint32_t kFormat = 2;
constexpr uint32_t kOldestFormat = 1;  // format 1: no exposure (read as zero)

class Writer {
 public:
  explicit Writer(const std::string& path) : path_(path), out_(path, std::ios::binary) {
    if (!out_) throw std::runtime_error("checkpoint " + path + ": cannot open for writing");
  }
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    out_.write(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  void bytes(const void* data, size_t n) { out_.write(static_cast<const char*>(data), n); }
  template <class T>
  void vec(const std::vector<T>& v) {
    put<uint64_t>(v.size());
    if (!v.empty()) bytes(v.data(), v.size() * sizeof(T));
  }
  void str(const std::string& s) {
    put<uint64_t>(s.size());
    bytes(s.data(), s.size());
  }
  void mat(const cv::Mat& m) {
    put<int32_t>(m.rows);
    put<int32_t>(m.cols);
    put<int32_t>(m.type());
    if (m.empty()) return;
    const cv::Mat c = m.isContinuous() ? m : m.clone();
    bytes(c.data, c.total() * c.elemSize());
  }
  void se3(const SE3& T) {
    const Eigen::Quaterniond q = T.quaternion();
    for (double v : {q.x(), q.y(), q.z(), q.w()}) put(v);
    for (int i = 0; i < 3; ++i) put(T.translation()[i]);
  }
  template <int R, int C>
  void matrix(const Eigen::Matrix<double, R, C>& m) {
    for (int i = 0; i < m.size(); ++i) put(m.data()[i]);
  }
  void finish() {
    out_.flush();
    if (!out_) throw std::runtime_error("checkpoint " + path_ + ": write failed (disk full?)");
    out_.close();
  }

 private:
  std::string path_;
  std::ofstream out_;
};

class Reader {
 public:
  explicit Reader(const std::string& path) : path_(path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("checkpoint " + path + ": cannot open");
    data_.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  [[noreturn]] void fail(const std::string& what) const {
    throw std::runtime_error("checkpoint " + path_ + ": " + what + " (at byte " +
                             std::to_string(pos_) + " of " + std::to_string(data_.size()) + ")");
  }
  void bytes(void* out, size_t n) {
    if (n > data_.size() - pos_) fail("truncated");
    std::memcpy(out, data_.data() + pos_, n);
    pos_ += n;
  }
  template <class T>
  T get() {
    T v;
    bytes(&v, sizeof(T));
    return v;
  }
  template <class T>
  void vec(std::vector<T>* v, size_t expected = SIZE_MAX) {
    const uint64_t n = get<uint64_t>();
    if (n > (data_.size() - pos_) / sizeof(T)) fail("array longer than the file");
    if (expected != SIZE_MAX && n != expected) fail("array size does not match the field");
    v->resize(n);
    if (n) bytes(v->data(), n * sizeof(T));
  }
  std::string str() {
    const uint64_t n = get<uint64_t>();
    if (n > data_.size() - pos_) fail("string longer than the file");
    std::string s(n, '\0');
    bytes(s.data(), n);
    return s;
  }
  cv::Mat mat() {
    const int rows = get<int32_t>(), cols = get<int32_t>(), type = get<int32_t>();
    if (rows == 0 || cols == 0) return cv::Mat();
    if (rows < 0 || cols < 0 || rows > 100000 || cols > 100000 ||
        (type != CV_8UC1 && type != CV_8UC3 && type != CV_32FC1))
      fail("bad image header");
    cv::Mat m(rows, cols, type);
    bytes(m.data, m.total() * m.elemSize());
    return m;
  }
  SE3 se3() {
    double q[4], t[3];
    for (double& v : q) v = get<double>();
    for (double& v : t) v = get<double>();
    const Eigen::Quaterniond quat(q[3], q[0], q[1], q[2]);
    if (!quat.coeffs().allFinite() || quat.norm() < 0.5) fail("bad pose");
    return SE3(quat, Vec3(t[0], t[1], t[2]));
  }
  template <int R, int C>
  void matrix(Eigen::Matrix<double, R, C>* m) {
    for (int i = 0; i < m->size(); ++i) m->data()[i] = get<double>();
  }
  bool done() const { return pos_ == data_.size(); }

 private:
  std::string path_;
  std::vector<char> data_;
  size_t pos_ = 0;
};

}  // namespace

void Mapper::saveCheckpoint(const std::string& path, bool with_images) const {
  const std::string tmp = path + ".tmp";
  {
    Writer w(tmp);
    w.bytes(kMagic, sizeof(kMagic));
    w.put(kFormat);
    w.put<uint8_t>(field_.initialized());
    if (field_.initialized()) {
      const FieldGeometry& g = field_.geometry();
      w.put<uint32_t>(g.numLevels());
      for (double s : g.voxel_size) w.put(s);
      w.put<int32_t>(g.sh_degree);
      w.put(g.density_bias);
      w.put<int64_t>(field_.version());
      const SparseAdam& adam = trainer_.optimizer();
      for (int l = 0; l < field_.numLevels(); ++l) {
        w.put<uint32_t>(field_.numBlocks(l));
        for (int b = 0; b < field_.numBlocks(l); ++b) {
          for (int k = 0; k < 3; ++k) w.put<int32_t>(field_.blockIndex(l, b)[k]);
          w.put<int64_t>(field_.blockVersion(l, b));
          w.put<uint8_t>(field_.blockChanged(l, b));
        }
        w.bytes(field_.levelData(l), field_.levelSize(l) * sizeof(float));
        // Optimiser state may lag behind allocation (no step since): pad with zeros.
        std::vector<float> m(field_.levelSize(l), 0.f), v(field_.levelSize(l), 0.f);
        std::vector<int32_t> steps(size_t(field_.numBlocks(l)) * Field::kBlockVoxels, 0);
        if (l < static_cast<int>(adam.firstMoments().size())) {
          std::copy(adam.firstMoments()[l].begin(), adam.firstMoments()[l].end(), m.begin());
          std::copy(adam.secondMoments()[l].begin(), adam.secondMoments()[l].end(), v.begin());
          std::copy(adam.steps()[l].begin(), adam.steps()[l].end(), steps.begin());
        }
        w.vec(m);
        w.vec(v);
        w.vec(steps);
      }
    }
    w.put<int64_t>(trainer_.steps());
    w.put<uint64_t>(trainer_.rngState());
    w.put<int64_t>(keyframes_.arrivals());
    w.put<uint32_t>(keyframes_.size());
    for (int i = 0; i < keyframes_.size(); ++i) {
      const KeyframeEntry& e = keyframes_.entry(i);
      const Keyframe& kf = e.keyframe;
      w.put(kf.keyframe_id);
      w.put(kf.version);
      w.put(kf.frame_index);
      w.put(kf.header.utime);
      w.put(kf.header.seq);
      w.str(kf.header.sender);
      w.se3(kf.T_world_cam);
      w.matrix(kf.covariance);
      const CameraModel& c = kf.camera;
      w.put<int32_t>(c.width);
      w.put<int32_t>(c.height);
      w.put<int8_t>(static_cast<int8_t>(c.type));
      for (double v : {c.fx, c.fy, c.cx, c.cy}) w.put(v);
      w.vec(c.distortion);
      w.se3(e.T_world_cam);
      w.put<uint8_t>(e.pose_refined);
      w.matrix(e.pose_m);
      w.matrix(e.pose_v);
      w.put(e.pose_steps);
      w.matrix(e.exposure);
      w.matrix(e.exposure_m);
      w.matrix(e.exposure_v);
      w.put(e.exposure_steps);
      w.put(e.loss_ema);
      w.put(e.rays_trained);
      w.put(e.arrival);
      w.put<uint8_t>(with_images);
      if (with_images) {
        for (const cv::Mat* m : {&kf.color, &kf.inv_depth, &kf.inv_depth_var, &kf.depth,
                                 &kf.depth_var, &kf.dynamic_mask})
          w.mat(*m);
        w.vec(e.pixels);
      }
    }
    w.finish();
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    throw std::runtime_error("checkpoint " + path + ": cannot rename " + tmp + " into place");
}

void Mapper::loadCheckpoint(const std::string& path) {
  Reader r(path);
  char magic[8];
  r.bytes(magic, sizeof(magic));
  if (std::memcmp(magic, kMagic, sizeof(kMagic)) != 0) r.fail("not a radslam mapper checkpoint");
  const uint32_t format = r.get<uint32_t>();
  if (format < kOldestFormat || format > kFormat)
    r.fail("format " + std::to_string(format) + ", this build reads " +
           std::to_string(kOldestFormat) + " to " + std::to_string(kFormat));
  // Everything is read into fresh objects first: a bad file leaves the mapper unchanged.
  Field field;
  SparseAdam adam(params_.trainer.adam);
  if (r.get<uint8_t>()) {
    FieldGeometry g;
    const uint32_t levels = r.get<uint32_t>();
    if (levels < 1 || levels > Field::kMaxLevels) r.fail("bad level count");
    for (uint32_t l = 0; l < levels; ++l) g.voxel_size.push_back(r.get<double>());
    g.sh_degree = r.get<int32_t>();
    g.density_bias = r.get<float>();
    try {
      field = Field(g);
    } catch (const std::exception& e) {
      r.fail(e.what());
    }
    field.restoreVersion(r.get<int64_t>());
    for (int l = 0; l < field.numLevels(); ++l) {
      const uint32_t blocks = r.get<uint32_t>();
      if (blocks > (1u << 26)) r.fail("absurd block count");
      for (uint32_t b = 0; b < blocks; ++b) {
        Eigen::Vector3i index;
        for (int k = 0; k < 3; ++k) index[k] = r.get<int32_t>();
        const int64_t version = r.get<int64_t>();
        const bool changed = r.get<uint8_t>() != 0;
        if (!Field::blockIndexInRange(index)) r.fail("bad block index");
        if (field.allocateBlock(l, index) != static_cast<int>(b)) r.fail("duplicate block");
        field.restoreBlockState(l, b, version, changed);
      }
      r.bytes(field.levelData(l), field.levelSize(l) * sizeof(float));
      adam.resize(field);
      r.vec(&adam.firstMoments()[l], field.levelSize(l));
      r.vec(&adam.secondMoments()[l], field.levelSize(l));
      r.vec(&adam.steps()[l], size_t(field.numBlocks(l)) * Field::kBlockVoxels);
    }
  }
  const int64_t steps = r.get<int64_t>();
  const uint64_t rng_state = r.get<uint64_t>();
  KeyframeStore store;
  store.setArrivals(r.get<int64_t>());
  const uint32_t count = r.get<uint32_t>();
  for (uint32_t i = 0; i < count; ++i) {
    KeyframeEntry e;
    Keyframe& kf = e.keyframe;
    kf.keyframe_id = r.get<int32_t>();
    kf.version = r.get<int32_t>();
    kf.frame_index = r.get<int64_t>();
    kf.header.utime = r.get<int64_t>();
    kf.header.seq = r.get<int64_t>();
    kf.header.sender = r.str();
    kf.T_world_cam = r.se3();
    r.matrix(&kf.covariance);
    CameraModel& c = kf.camera;
    c.width = r.get<int32_t>();
    c.height = r.get<int32_t>();
    c.type = static_cast<CameraModel::Type>(r.get<int8_t>());
    c.fx = r.get<double>();
    c.fy = r.get<double>();
    c.cx = r.get<double>();
    c.cy = r.get<double>();
    r.vec(&c.distortion);
    e.T_world_cam = r.se3();
    e.pose_refined = r.get<uint8_t>() != 0;
    r.matrix(&e.pose_m);
    r.matrix(&e.pose_v);
    e.pose_steps = r.get<int64_t>();
    if (format >= 2) {
      r.matrix(&e.exposure);
      r.matrix(&e.exposure_m);
      r.matrix(&e.exposure_v);
      e.exposure_steps = r.get<int64_t>();
    }
    e.loss_ema = r.get<double>();
    e.rays_trained = r.get<int64_t>();
    e.arrival = r.get<int64_t>();
    if (r.get<uint8_t>()) {
      for (cv::Mat* m : {&kf.color, &kf.inv_depth, &kf.inv_depth_var, &kf.depth, &kf.depth_var,
                         &kf.dynamic_mask})
        *m = r.mat();
      r.vec(&e.pixels);
      const bool sizes_ok = kf.color.cols == c.width && kf.color.rows == c.height &&
                            kf.depth.size == kf.color.size && kf.depth_var.size == kf.color.size;
      if (!sizes_ok) r.fail("keyframe " + std::to_string(kf.keyframe_id) + ": bad image sizes");
      for (int32_t p : e.pixels)
        if (p < 0 || p >= c.width * c.height) r.fail("bad pixel index");
    }
    store.restore(std::move(e));
  }
  if (!r.done()) r.fail("trailing bytes");
  field_ = std::move(field);
  trainer_.optimizer() = std::move(adam);
  trainer_.restoreState(steps, rng_state);
  keyframes_ = std::move(store);
}

}  // namespace radslam
