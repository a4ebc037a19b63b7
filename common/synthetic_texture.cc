#include "common/synthetic_texture.h"

#include <algorithm>
#include <cmath>

namespace radslam::synth {
namespace {

constexpr double kTwoPi = 6.283185307179586;

// ---------------------------------------------------------------------------------------------
// Procedural texture building blocks. All are pure functions of (u, v) in metres and a seed, so
// renders are deterministic and identical whichever thread computes a pixel.

inline uint32_t mix32(uint32_t h) {
  h ^= h >> 16;
  h *= 0x7feb352dU;
  h ^= h >> 15;
  h *= 0x846ca68bU;
  h ^= h >> 16;
  return h;
}

/// floor() as an integer, inlined (std::floor is a library call without SSE4.1).
inline int64_t fastFloor(double x) {
  const int64_t i = static_cast<int64_t>(x);
  return i - (static_cast<double>(i) > x ? 1 : 0);
}

inline uint32_t hashCell(int64_t x, int64_t y, uint32_t seed) {
  return mix32(static_cast<uint32_t>(x) * 0x8da6b343U + static_cast<uint32_t>(y) * 0xd8163841U +
               seed * 0xcb1ab31fU);
}

inline double floorD(double x) { return static_cast<double>(fastFloor(x)); }

/// Uniform in [0, 1) per integer cell.
inline double cellRandom(double x, double y, uint32_t seed) {
  return hashCell(fastFloor(x), fastFloor(y), seed) * (1.0 / 4294967296.0);
}

inline double clamp01(double x) { return x < 0 ? 0 : (x > 1 ? 1 : x); }
inline double smoothstep(double a, double b, double x) {
  const double t = clamp01((x - a) / (b - a));
  return t * t * (3 - 2 * t);
}
inline Vec3 mix(const Vec3& a, const Vec3& b, double t) { return a + t * (b - a); }

/// Weight of a pattern component of spatial frequency f (cycles/m) for a pixel footprint fw (m):
/// 1 up to 4 pixels per cycle, 0 at the Nyquist limit of 2 pixels per cycle.
inline double lodWeight(double f, double fw) { return clamp01(2.0 - 4.0 * f * fw); }

/// A fixed 1024-periodic lattice of random values, addressed through a permutation (Perlin's
/// scheme): cheaper than hashing every corner, and the period is invisible under fBm's
/// per-octave rotation and seed offsets.
struct NoiseLattice {
  static constexpr uint32_t kMask = 1023;
  uint16_t perm[kMask + 1];
  double value[kMask + 1];
  NoiseLattice() {
    for (uint32_t i = 0; i <= kMask; ++i) perm[i] = static_cast<uint16_t>(i);
    uint32_t state = 0x2545f491U;
    for (uint32_t i = kMask; i > 0; --i) {
      state = mix32(state + i);
      std::swap(perm[i], perm[state % (i + 1)]);
    }
    for (uint32_t i = 0; i <= kMask; ++i)
      value[i] = mix32(i * 0x9e3779b9U + 7U) * (2.0 / 4294967296.0) - 1.0;
  }
};
const NoiseLattice kLattice;

/// Value noise with cubic interpolation, in [-1, 1]; `offset` (a hashed seed) shifts the
/// lattice.
inline double valueNoise(double x, double y, uint32_t offset) {
  constexpr uint32_t M = NoiseLattice::kMask;
  const int64_t ix = fastFloor(x), iy = fastFloor(y);
  const double tx = x - static_cast<double>(ix), ty = y - static_cast<double>(iy);
  const double sx = tx * tx * (3 - 2 * tx), sy = ty * ty * (3 - 2 * ty);
  const uint32_t i0 = (static_cast<uint32_t>(ix) + offset) & M;
  const uint32_t j0 = static_cast<uint32_t>(iy) + (offset >> 10);
  const uint32_t p0 = kLattice.perm[i0], p1 = kLattice.perm[(i0 + 1) & M];
  const double a = kLattice.value[kLattice.perm[(p0 + j0) & M]];
  const double b = kLattice.value[kLattice.perm[(p1 + j0) & M]];
  const double c = kLattice.value[kLattice.perm[(p0 + j0 + 1) & M]];
  const double d = kLattice.value[kLattice.perm[(p1 + j0 + 1) & M]];
  const double top = a + sx * (b - a), bottom = c + sx * (d - c);
  return top + sy * (bottom - top);
}

/// Frequency ratio of successive fBm octaves: above the usual 2 so fewer octaves span the scales
/// from a surface's size down to a pixel (the renderer's main cost).
constexpr double kLacunarity = 2.5;

/// Fractal sum of value noise from `freq` (cycles/m) up, each octave kLacunarity times the
/// frequency and gain times the amplitude, and rotated (hides the lattice). Octaves too fine for
/// the footprint fade out, so the result tends to 0 (the mean) far away. Roughly in [-1, 1], std
/// about 0.3.
double fbm(double x, double y, uint32_t seed, double freq, int octaves, double fw,
           double gain = 0.5) {
  double sum = 0, amp = 1;
  uint32_t offset = mix32(seed);
  for (int o = 0; o < octaves; ++o) {
    const double w = lodWeight(freq, fw);
    // Finer octaves are all below the footprint, or too faint to change a grey level.
    if (w <= 0 || amp < 0.07) break;
    sum += w * amp * valueNoise(x * freq, y * freq, offset);
    offset += 0x9e3779b9U;
    const double xr = 0.8 * x - 0.6 * y;
    y = 0.6 * x + 0.8 * y;
    x = xr;
    freq *= kLacunarity;
    amp *= gain;
  }
  return sum * (1.0 - gain);  // normalised by the sum of all amplitudes, 1 / (1 - gain)
}

/// Fraction of the footprint [x - w/2, x + w/2] inside [a, b].
inline double boxCoverage(double x, double a, double b, double w) {
  if (w <= 1e-9) return (x >= a && x < b) ? 1 : 0;
  const double lo = std::max(x - 0.5 * w, a), hi = std::min(x + 0.5 * w, b);
  return hi > lo ? (hi - lo) / w : 0;
}

/// Fraction of the footprint inside the periodic pulses [a + k period, a + len + k period].
__attribute__((always_inline)) inline double pulseCoverage(double x, double period, double a,
                                                           double len, double w) {
  const double inv = 1.0 / period;  // folded to a constant where period is one
  const double r = x - a - floorD((x - a) * inv) * period, h = 0.5 * w;
  // Most footprints lie wholly inside or wholly outside a pulse.
  if (r >= h && r + h <= len) return 1;
  if (r - h >= len && r + h <= period) return 0;
  if (w <= 1e-9) return r < len ? 1 : 0;
  auto integral = [&](double s) {
    const double k = floorD((s - a) * inv);
    return k * len + std::min(s - a - k * period, len);
  };
  return clamp01((integral(x + h) - integral(x - h)) / w);
}

inline double unionOf(double a, double b) { return a + b - a * b; }

// ---------------------------------------------------------------------------------------------
// Materials.

Vec3 asphalt(const Material& m, double u, double v, double fw) {
  const double n = fbm(u, v, m.seed, 0.3, 9, fw, 0.55);
  const double fine = fbm(u, v, m.seed + 17, 6.0, 3, fw, 0.7);  // grain: 6, 15, 37 cycles/m
  const double patch = smoothstep(0.08, 0.22, fbm(u, v, m.seed + 31, 0.05, 2, fw));
  Vec3 c = m.color_a * (1.0 + 0.9 * n + 1.0 * fine - 0.25 * patch);
  // Markings: dashed centre line, solid edge lines, a zebra crossing every 150 m.
  const double hw = m.scale;
  double paint = boxCoverage(v, -0.075, 0.075, fw) * pulseCoverage(u, 9.0, 0.0, 3.0, fw);
  paint += boxCoverage(v, hw - 0.35, hw - 0.2, fw) + boxCoverage(v, -hw + 0.2, -hw + 0.35, fw);
  const double k = floorD(u / 150.0);
  paint += boxCoverage(u - 150.0 * k, 60.0, 64.0, fw) * pulseCoverage(v, 1.0, 0.25, 0.5, fw) *
           boxCoverage(v, -hw + 0.6, hw - 0.6, fw);
  if (paint <= 0) return c;
  const double worn = 0.85 + 0.5 * fbm(u, v, m.seed + 5, 2.0, 5, fw);
  return mix(c, m.color_b * worn, clamp01(paint));
}

Vec3 ground(const Material& m, double u, double v, double fw) {
  const double t = clamp01(0.5 + 1.4 * fbm(u, v, m.seed, 0.15, 10, fw, 0.6));
  return mix(m.color_a, m.color_b, t) * (1.0 + 0.4 * fbm(u, v, m.seed + 9, 8.0, 4, fw));
}

Vec3 tiles(const Material& m, double u, double v, double fw) {
  const double s = m.scale, g = 0.03 * s + 0.004;
  const double grout = unionOf(pulseCoverage(u, s, 0, g, fw), pulseCoverage(v, s, 0, g, fw));
  const double jitter = (cellRandom(u / s, v / s, m.seed) - 0.5) * lodWeight(1.0 / s, fw);
  const Vec3 tile = mix(m.color_a, m.color_b, 0.5 + jitter) *
                    (1.0 + 0.45 * fbm(u, v, m.seed + 1, 1.0 / s, 7, fw, 0.55));
  return mix(tile, 0.45 * m.color_a, grout);
}

Vec3 brickWall(const Material& m, double u, double v, double fw) {
  constexpr double kW = 0.25, kH = 0.075, kMortar = 0.012;
  const double row = floorD(v / kH);
  const double shift = std::fmod(row, 2.0) != 0 ? 0.5 * kW : 0.0;
  const double mortar =
      unionOf(pulseCoverage(v, kH, 0, kMortar, fw), pulseCoverage(u + shift, kW, 0, kMortar, fw));
  const double jitter = (cellRandom((u + shift) / kW, row, m.seed) - 0.5) * lodWeight(1 / kH, fw);
  Vec3 c = mix(m.color_a, m.color_b, clamp01(0.5 + 0.9 * jitter)) *
           (1.0 + 0.3 * fbm(u, v, m.seed + 1, 2.0, 7, fw));
  c *= 1.0 - 0.3 * std::max(0.0, fbm(u, 0.3 * v, m.seed + 5, 0.2, 2, fw));  // stains
  return mix(c, Vec3(0.72, 0.7, 0.64), mortar);
}

Vec3 plasterWall(const Material& m, double u, double v, double fw) {
  Vec3 c = m.color_a * (1.0 + 0.35 * fbm(u, v, m.seed, 0.4, 10, fw, 0.55));
  c *= 1.0 - 0.25 * std::max(0.0, fbm(4.0 * u, 0.25 * v, m.seed + 9, 0.5, 2, 4.0 * fw));
  return mix(c, m.color_b, pulseCoverage(v, 3.0, 2.75, 0.25, fw));  // storey cornices
}

/// A facade: `wall` with, when the material has them, a grid of 1.4 x 1.6 m windows every
/// 3.2 m, 3 m per storey, and shop windows on the ground floor.
Vec3 facade(const Material& m, double u, double v, double fw,
            Vec3 (*wall)(const Material&, double, double, double)) {
  if (!m.windows) return wall(m, u, v, fw);
  double win, outer;
  if (v < 3.0) {
    win = pulseCoverage(u, 6.4, 0.5, 4.5, fw) * boxCoverage(v, 0.4, 2.6, fw);
    outer = pulseCoverage(u, 6.4, 0.4, 4.7, fw) * boxCoverage(v, 0.3, 2.7, fw);
  } else {
    win = pulseCoverage(u, 3.2, 0.9, 1.4, fw) * pulseCoverage(v, 3.0, 0.8, 1.6, fw);
    outer = pulseCoverage(u, 3.2, 0.8, 1.6, fw) * pulseCoverage(v, 3.0, 0.7, 1.8, fw);
  }
  if (outer <= 0) return wall(m, u, v, fw);
  // Area-weighted: wall outside the frame, frame, glass (the wall only when partly visible).
  outer = clamp01(outer);
  win = std::min(clamp01(win), outer);
  Vec3 c = Vec3(0.82, 0.82, 0.78) * (outer - win);
  if (outer < 1) c += (1 - outer) * wall(m, u, v, fw);
  if (win <= 0) return c;
  const double cell = cellRandom(u / 3.2, v / 3.0, m.seed + 3);
  const double reflect = std::fmod(std::max(v, 0.0), 3.0) / 3.0;
  Vec3 glass = Vec3(0.10, 0.12, 0.16) * (1.0 + 0.8 * reflect) +
               Vec3::Constant(0.06 * fbm(u, v, m.seed + 77, 1.5, 6, fw));
  const double curtain =
      pulseCoverage(u, 3.2, 0.9, 0.5, fw) * lodWeight(1.0 / 3.2, fw) * (cell > 0.55 ? 1.0 : 0.0);
  glass = mix(glass, Vec3(0.55, 0.45, 0.32) * (0.8 + 0.6 * cell), curtain);
  return c + win * glass;
}

Vec3 planks(const Material& m, double u, double v, double fw) {
  const double length = m.scale, width = 0.16;
  const double row = floorD(v / width);
  const double offset = cellRandom(row, 7, m.seed) * length;
  const double gap = unionOf(pulseCoverage(v, width, 0, 0.005, fw),
                             pulseCoverage(u + offset, length, 0, 0.005, fw));
  const double jitter =
      (cellRandom((u + offset) / length, row, m.seed + 1) - 0.5) * lodWeight(1 / width, fw);
  const uint32_t plank_seed = m.seed + 13U * static_cast<uint32_t>(static_cast<int64_t>(row));
  const double grain = fbm(0.25 * u, 6.0 * v, plank_seed, 1.0, 6, 6.0 * fw, 0.6);
  const Vec3 c = mix(m.color_a, m.color_b, clamp01(0.5 + 1.2 * grain + 0.7 * jitter));
  return mix(c, 0.3 * m.color_a, gap);
}

/// Saturated colours: a cosine palette driven by a detailed and a coarse fBm.
Vec3 vividPattern(double u, double v, uint32_t seed, double freq, double fw) {
  const double t =
      1.2 * fbm(u, v, seed, freq, 7, fw, 0.55) + fbm(u, v, seed + 7919U, 0.5 * freq, 3, fw);
  Vec3 c;
  for (int i = 0; i < 3; ++i) c[i] = 0.5 + 0.45 * std::cos(kTwoPi * (1.3 * t + 0.33 * i + 0.1));
  return c;
}

Vec3 wallpaper(const Material& m, double u, double v, double fw) {
  const double stripe =
      0.55 * pulseCoverage(u, 0.16, 0, 0.07, fw) + 0.35 * pulseCoverage(u, 0.16, 0.11, 0.012, fw);
  Vec3 c = mix(m.color_a, m.color_b, stripe) * (1.0 + 0.25 * fbm(u, v, m.seed, 1.5, 7, fw));
  // A poster in most 1.7 m wide cells.
  const double cell_w = 1.7, k = floorD(u / cell_w);
  const double h0 = cellRandom(k, 1, m.seed), h1 = cellRandom(k, 2, m.seed);
  if (h0 < 0.7) {
    const double u0 = k * cell_w + 0.2 + 0.2 * h1, u1 = u0 + 0.7 + 0.5 * h0;
    const double v0 = 0.95 + 0.3 * h1, v1 = v0 + 0.6 + 0.5 * h0;
    const double outer =
        boxCoverage(u, u0 - 0.03, u1 + 0.03, fw) * boxCoverage(v, v0 - 0.03, v1 + 0.03, fw);
    if (outer > 0) {
      const double inner = boxCoverage(u, u0, u1, fw) * boxCoverage(v, v0, v1, fw);
      c = mix(c, Vec3(0.08, 0.07, 0.06), outer - inner);
      c = mix(c, vividPattern(u, v, m.seed + 1000U * static_cast<uint32_t>(k), 1.0, fw), inner);
    }
  }
  const double board = boxCoverage(v, -1.0, 0.1, fw);
  if (board <= 0) return c;
  const Vec3 skirting = Vec3(0.36, 0.22, 0.12) * (1.0 + 0.3 * fbm(u, v, m.seed + 3, 4.0, 4, fw));
  return mix(c, skirting, board);
}

Vec3 wood(const Material& m, double u, double v, double fw) {
  const double ring_freq = 12.0;
  const double t = (v + 0.08 * fbm(u, v, m.seed, 1.0, 4, fw)) * ring_freq;
  const double rings = std::sin(kTwoPi * t) * lodWeight(ring_freq, fw);
  const double grain = fbm(0.3 * u, 3.0 * v, m.seed + 3, 2.0, 6, 3.0 * fw);
  return mix(m.color_a, m.color_b, clamp01(0.45 + 0.25 * rings + 0.9 * grain));
}

Vec3 books(const Material& m, double u, double v, double fw) {
  constexpr double kShelf = 0.4, kBook = 0.035;
  const double board = pulseCoverage(v, kShelf, 0, 0.03, fw);
  const double row = floorD(v / kShelf);
  const double h0 = cellRandom(u / kBook, row, m.seed), h1 = cellRandom(u / kBook, row, m.seed + 1);
  const double h2 = cellRandom(u / kBook, row, m.seed + 2);
  const double lod = lodWeight(1.0 / kBook, fw);
  Vec3 spine = Vec3(0.15 + 0.7 * h0, 0.15 + 0.7 * h1, 0.15 + 0.7 * h2);
  spine = mix(Vec3(0.4, 0.3, 0.25), spine, lod);
  const double in_row = v - row * kShelf;
  const double top = 0.25 + 0.1 * h2 * lod;
  const double band = boxCoverage(in_row, 0.12, 0.15, fw) * lod;
  spine = mix(spine, Vec3(0.9, 0.85, 0.6), band);
  spine = mix(spine, 0.3 * spine, pulseCoverage(u, kBook, 0, 0.004, fw));
  const Vec3 back = Vec3(0.08, 0.06, 0.05);
  Vec3 c = mix(back, spine, boxCoverage(in_row, 0.03, top, fw));
  c *= 1.0 + 0.2 * fbm(u, v, m.seed + 9, 4.0, 5, fw);
  return mix(c, wood(m, u, v, fw), board);
}

Vec3 door(const Material& m, double u, double v, double fw) {
  const Vec3 base = wood(m, v, u, fw);  // vertical grain
  const double pu = m.scale, pv = 1.5 * m.scale;
  const double gu =
      pulseCoverage(u, pu, 0.07, 0.02, fw) + pulseCoverage(u, pu, pu - 0.09, 0.02, fw);
  const double gv =
      pulseCoverage(v, pv, 0.07, 0.02, fw) + pulseCoverage(v, pv, pv - 0.09, 0.02, fw);
  const double in_u = pulseCoverage(u, pu, 0.07, pu - 0.14, fw);
  const double in_v = pulseCoverage(v, pv, 0.07, pv - 0.14, fw);
  return mix(base, 0.4 * base, clamp01(gu * in_v + gv * in_u));
}

Vec3 paint(const Material& m, double u, double v, double fw) {
  Vec3 c = m.color_a * (1.0 + 0.35 * fbm(u, v, m.seed, 1.0, 7, fw));
  const double stripe = boxCoverage(v, 0.62, 0.72, fw) +
                        pulseCoverage(u, 0.5, 0.0, 0.06, fw) * boxCoverage(v, 0.38, 0.55, fw);
  c = mix(c, m.color_b, clamp01(stripe));
  const double logo = boxCoverage(u, -1.2, 0.5, fw) * boxCoverage(v, 0.76, 0.98, fw);
  if (logo > 0) {
    const double chk =
        std::abs(pulseCoverage(u, 0.16, 0, 0.08, fw) - pulseCoverage(v, 0.16, 0, 0.08, fw));
    c = mix(c, mix(Vec3(0.95, 0.95, 0.9), m.color_b, chk), logo);
  }
  const double low = smoothstep(0.55, 0.3, v);
  if (low <= 0) return c;
  const double dirt = low * (0.5 + fbm(2 * u, 2 * v, m.seed + 5, 1, 5, 2 * fw));
  return c * (1.0 - 0.5 * clamp01(dirt));
}

Vec3 glass(const Material& m, double u, double v, double fw) {
  const double reflect = 0.5 + fbm(u + 0.8 * v, 0.3 * v, m.seed, 0.5, 5, fw);
  Vec3 c = Vec3(0.07, 0.09, 0.12) + Vec3::Constant(0.14 * clamp01(reflect));
  return mix(c, m.color_a, pulseCoverage(u, m.scale, 0, 0.08, fw));
}

Vec3 rubber(const Material& m, double u, double v, double fw) {
  const double tread = pulseCoverage(u + v, 0.05, 0, 0.02, fw);
  return m.color_a * (1.0 + 0.6 * fbm(u, v, m.seed, 4.0, 5, fw) - 0.3 * tread);
}

Vec3 fabric(const Material& m, double u, double v, double fw) {
  const double s = m.scale;
  const double cu = pulseCoverage(u, 2 * s, 0, s, fw), cv = pulseCoverage(v, 2 * s, 0, s, fw);
  const double checker = cu + cv - 2 * cu * cv;
  const double lines = unionOf(pulseCoverage(u, s, 0.4 * s, 0.08 * s, fw),
                               pulseCoverage(v, s, 0.4 * s, 0.08 * s, fw));
  const Vec3 c = mix(m.color_a, m.color_b, 0.65 * checker + 0.35 * lines);
  return c * (1.0 + 0.3 * fbm(u, v, m.seed, 2.0 / s, 7, fw));
}

Vec3 metal(const Material& m, double u, double v, double fw) {
  const double streak = fbm(6.0 * u, 0.4 * v, m.seed, 1.0, 6, 6.0 * fw);
  const Vec3 c = m.color_a * (1.0 + 0.4 * streak);
  return mix(c, m.color_b, pulseCoverage(v, m.scale, 0, 0.06, fw));
}

Vec3 doorway(const Material& m, double u, double v, double fw) {
  return m.color_a * (1.0 + 0.8 * fbm(u, v, m.seed, 0.7, 8, fw, 0.6)) +
         m.color_b * smoothstep(0.0, 2.0, v);
}

Vec3 graffiti(const Material& m, double u, double v, double fw) {
  Vec3 c = vividPattern(u, v, m.seed, 0.5, fw);
  const double rib = pulseCoverage(v, 0.3, 0, 0.03, fw);
  // Letter-like dark blocks in a band.
  const double block_w = 0.25, block_h = 0.35;
  const double on = cellRandom(u / block_w, v / block_h, m.seed + 5) > 0.45 ? 1.0 : 0.0;
  const double letters = on * lodWeight(1.0 / 0.17, fw) * boxCoverage(v, 1.6, 2.65, fw) *
                         pulseCoverage(u, block_w, 0.04, 0.17, fw) *
                         pulseCoverage(v, block_h, 0.05, 0.25, fw);
  c = mix(c, Vec3(0.05, 0.05, 0.08), letters);
  return mix(c, 0.35 * c, rib);
}

}  // namespace

Vec3 materialAlbedo(const Material& m, double u, double v, double fw) {
  switch (m.kind) {
    case MaterialKind::kAsphalt:
      return asphalt(m, u, v, fw);
    case MaterialKind::kGround:
      return ground(m, u, v, fw);
    case MaterialKind::kTiles:
      return tiles(m, u, v, fw);
    case MaterialKind::kBricks:
      return facade(m, u, v, fw, brickWall);
    case MaterialKind::kPlaster:
      return facade(m, u, v, fw, plasterWall);
    case MaterialKind::kPlanks:
      return planks(m, u, v, fw);
    case MaterialKind::kWallpaper:
      return wallpaper(m, u, v, fw);
    case MaterialKind::kWood:
      return wood(m, u, v, fw);
    case MaterialKind::kBooks:
      return books(m, u, v, fw);
    case MaterialKind::kDoor:
      return door(m, u, v, fw);
    case MaterialKind::kPaint:
      return paint(m, u, v, fw);
    case MaterialKind::kGlass:
      return glass(m, u, v, fw);
    case MaterialKind::kRubber:
      return rubber(m, u, v, fw);
    case MaterialKind::kFabric:
      return fabric(m, u, v, fw);
    case MaterialKind::kMetal:
      return metal(m, u, v, fw);
    case MaterialKind::kDoorway:
      return doorway(m, u, v, fw);
    case MaterialKind::kGraffiti:
      return graffiti(m, u, v, fw);
  }
  return m.color_a;
}

Vec3 skyColor(const Vec3& d, double pixel_angle, uint32_t seed) {
  const double e = d.z() / d.norm();  // sine of the elevation
  const Vec3 horizon(0.82, 0.86, 0.9), zenith(0.3, 0.5, 0.85);
  Vec3 c = mix(horizon, zenith, std::sqrt(std::max(e, 0.0)));
  if (e > 0.02) {
    // Clouds on a layer 1.5 km up; footprint grows as the layer is seen more obliquely.
    constexpr double kLayer = 1500.0;
    const double x = d.x() / d.z() * kLayer, y = d.y() / d.z() * kLayer;
    const double fw = pixel_angle * kLayer / (e * e);
    const double cloud = smoothstep(-0.05, 0.45, fbm(x, y, seed, 1.0 / 1200.0, 8, fw, 0.55));
    c = mix(c, Vec3(0.96, 0.96, 0.97), 0.85 * cloud * smoothstep(0.02, 0.15, e));
  }
  return c;
}

}  // namespace radslam::synth
