#include "cip/mesh/lewiner_marching_cubes.h"

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <string>

#include "cip/core/error.h"

namespace cip {

namespace {

#include "cip/mesh/lewiner_tables.inc"

/// scikit-image's "FLT_EPSILON", which is numpy.spacing(1.0): the double epsilon.
constexpr double kEps = std::numeric_limits<double>::epsilon();

/// Corner offsets (x, y, z) of Lewiner's corner numbering; x is array axis 2, z array axis 0.
constexpr int kCorner[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0},
                               {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};

/// What a slab of cell layers adds, before it is joined to the slabs below it: its vertices, numbered from 0
/// in the serial walk's order, and its faces, where -2 - n names the n-th vertex of its bottom plane, which
/// the slab below creates (`bottomSlots`: that vertex's slot in the slab below's `top` layer); the gradients
/// and values those vertices get from this slab, in the order the serial walk adds them.
struct Slab {
  LewinerMesh mesh;  ///< x, y, z order, normals not yet normalised
  /// The filled slots of the slab's top plane (slot, vertex), by slot: what the slab above refers to.
  std::vector<std::pair<std::size_t, std::int32_t>> top;
  std::vector<std::size_t> bottomSlots;
  std::vector<float> bottomValues;
  std::vector<std::pair<std::int32_t, std::array<float, 3>>> bottomGradients;
};

/// The state of one pass: the current cell, the two layers of edge-to-vertex slots and the output (in
/// scikit-image's internal x, y, z order; flipped to array axis order at the end).
class Marcher {
 public:
  Marcher(std::int64_t nx, std::int64_t ny, int step)
      : nx_(nx), step_(step), layer1_(static_cast<std::size_t>(nx * ny * 4), -1), layer2_(layer1_) {}

  void newLayer() {
    std::swap(layer1_, layer2_);
    std::fill(layer2_.begin(), layer2_.end(), -1);
  }
  /// Kept out of line: inlined into the sample reading of float64 volumes, GCC 12 at -O3 (its SLP
  /// vectorizer) gave normals that differed from scikit-image's in the last bits; out of line they match.
  [[gnu::noinline]] void setCell(std::int64_t x, std::int64_t y, std::int64_t z, const float (&samples)[8],
                                 double level);
  void classicCell();
  void lewinerCell();
  void reserveFor(double done);
  /// From now on, vertices on the bottom plane of layer `z` belong to the slab below (see Slab).
  void bottomFromBelow(std::int64_t z) {
    external_ = true;
    firstZ_ = z;
  }
  Slab take() {
    Slab slab;
    slab.mesh = std::move(out_);
    for (std::size_t key = 0; key < layer2_.size(); ++key)
      if (layer2_[key] >= 0) slab.top.emplace_back(key, layer2_[key]);
    slab.bottomSlots = std::move(bottomSlots_);
    slab.bottomValues = std::move(bottomValues_);
    slab.bottomGradients = std::move(bottomGradients_);
    return slab;
  }

 private:
  void triangles(const std::int8_t* edges, int count);
  void edgeVertex(int edge);
  std::int32_t newVertex(double x, double y, double z);
  void addGradient(std::int32_t vertex, float gx, float gy, float gz);
  void centreVertex();
  bool testFace(int face) const;
  bool testInterior(int kase, int config, int subconfig, int s) const;
  double interiorEdgeT(int edge, double& bt, double& ct, double& dt) const;
  void case7(int config);
  void case10or12(int kase, int config);
  void case13(int config);

  std::int64_t nx_;
  int step_;
  std::vector<std::int32_t> layer1_, layer2_;  ///< 4 slots per cell: edges along x, y, z, interior
  std::int64_t x_ = 0, y_ = 0, z_ = 0;
  double v_[8] = {};        ///< samples minus level, Lewiner's numbering
  double byBits_[8] = {};   ///< the same, indexed by x + 2y + 4z
  double grad_[8][3] = {};  ///< one-sided differences at each corner (Lewiner's numbering)
  double range_ = 0;        ///< max(0, v) - min(0, v) over the corners
  int index_ = 0;           ///< bit c set for v_[c] > 0
  bool centreReady_ = false;
  double centre_[3] = {}, centreGrad_[3] = {};
  LewinerMesh out_;  ///< positions and normals in x, y, z order until orient()
  bool external_ = false;
  std::int64_t firstZ_ = 0;
  std::vector<std::size_t> bottomSlots_;
  std::vector<float> bottomValues_;
  std::vector<std::pair<std::int32_t, std::array<float, 3>>> bottomGradients_;
  std::array<std::int32_t, 3> face_{};
  int corners_ = 0;  ///< corners of face_ filled
};

void Marcher::setCell(std::int64_t x, std::int64_t y, std::int64_t z, const float (&samples)[8],
                      double level) {
  x_ = x;
  y_ = y;
  z_ = z;
  index_ = 0;
  for (int c = 0; c < 8; ++c) {
    v_[c] = static_cast<double>(samples[c]) - level;
    if (v_[c] > 0.0) index_ |= 1 << c;
  }
  centreReady_ = false;
}

/// The per-cell quantities scikit-image computes before adding a cell's triangles. Its edge vertices take
/// the gradient of the corner whose Lewiner number equals the xyz bit index of the edge's end, which is a
/// different corner for bit indices 2, 3, 6 and 7; kept as is, since the normals must match.
void Marcher::triangles(const std::int8_t* edges, int count) {
  double lo = 0.0, hi = 0.0;
  for (int c = 0; c < 8; ++c) {
    byBits_[kCorner[c][0] + 2 * kCorner[c][1] + 4 * kCorner[c][2]] = v_[c];
    hi = std::max(hi, v_[c]);
    lo = std::min(lo, v_[c]);
  }
  range_ = hi - lo;
  const double* v = v_;
  const double g[8][3] = {{v[0] - v[1], v[0] - v[3], v[0] - v[4]}, {v[0] - v[1], v[1] - v[2], v[1] - v[5]},
                          {v[3] - v[2], v[1] - v[2], v[2] - v[6]}, {v[3] - v[2], v[0] - v[3], v[3] - v[7]},
                          {v[4] - v[5], v[4] - v[7], v[0] - v[4]}, {v[4] - v[5], v[5] - v[6], v[1] - v[5]},
                          {v[7] - v[6], v[5] - v[6], v[2] - v[6]}, {v[7] - v[6], v[4] - v[7], v[3] - v[7]}};
  std::copy(&g[0][0], &g[0][0] + 24, &grad_[0][0]);
  for (int i = 0; i < 3 * count; ++i) edgeVertex(edges[i]);
}

std::int32_t Marcher::newVertex(double x, double y, double z) {
  const std::size_t n = out_.values.size();
  if (n >= static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
    throw Error("the mesh has more vertices than int32 faces can index");
  out_.vertices.push_back({static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)});
  out_.normals.push_back({0.0f, 0.0f, 0.0f});
  out_.values.push_back(0.0f);
  return static_cast<std::int32_t>(n);
}

void Marcher::addGradient(std::int32_t vertex, float gx, float gy, float gz) {
  if (vertex < 0) return bottomGradients_.push_back({-2 - vertex, {gx, gy, gz}});
  auto& n = out_.normals[static_cast<std::size_t>(vertex)];
  n[0] += gx;
  n[1] += gy;
  n[2] += gz;
}

/// The interior vertex: the mean of the corners weighted by 1 / (eps + |v|), and the same mean of the
/// corners' differences as its gradient.
void Marcher::centreVertex() {
  double w[8], f[3] = {0.0, 0.0, 0.0}, total = 0.0;
  for (int c = 0; c < 8; ++c) {
    w[c] = 1.0 / (kEps + std::abs(v_[c]));
    for (int a = 0; a < 3; ++a) f[a] += kCorner[c][a] * w[c];
    total += w[c];
  }
  const double origin[3] = {static_cast<double>(x_), static_cast<double>(y_), static_cast<double>(z_)};
  for (int a = 0; a < 3; ++a) {
    centre_[a] = origin[a] + step_ * f[a] / total;
    centreGrad_[a] = 0.0;
    for (int c = 0; c < 8; ++c) centreGrad_[a] += w[c] * grad_[c][a];
  }
  centreReady_ = true;
}

/// Adds one face corner on `edge` (0-11, or 12 for the interior vertex), creating the vertex on first use:
/// slots are per cell (x, y edges in the layer of their z, z edges and the interior in the lower layer).
void Marcher::edgeVertex(int edge) {
  std::int64_t slot = nx_ * y_ + x_;
  int kind = 0;
  std::vector<std::int32_t>* layer = &layer1_;
  if (edge < 8) {
    const int e = edge & 3;
    if (edge >= 4) layer = &layer2_;
    if (e == 1) slot += step_;
    if (e == 2) slot += nx_ * step_;
    kind = (e == 1 || e == 3) ? 1 : 0;
  } else if (edge < 12) {
    kind = 2;
    if (edge == 9) slot += step_;
    if (edge == 10) slot += nx_ * step_ + step_;
    if (edge == 11) slot += nx_ * step_;
  } else {
    kind = 3;
  }
  const auto key = static_cast<std::size_t>(4 * slot + kind);
  std::int32_t& vertex = (*layer)[key];
  float g[2][3] = {};
  if (edge == 12) {
    if (!centreReady_) centreVertex();
    if (vertex == -1) vertex = newVertex(centre_[0], centre_[1], centre_[2]);
    addGradient(vertex, static_cast<float>(centreGrad_[0]), static_cast<float>(centreGrad_[1]),
                static_cast<float>(centreGrad_[2]));
  } else {
    const int a = kEdgeX[edge][0] + 2 * kEdgeY[edge][0] + 4 * kEdgeZ[edge][0];
    const int b = kEdgeX[edge][1] + 2 * kEdgeY[edge][1] + 4 * kEdgeZ[edge][1];
    const double wa = 1.0 / (kEps + std::abs(byBits_[a])), wb = 1.0 / (kEps + std::abs(byBits_[b]));
    if (vertex == -1 && external_ && edge < 4 && z_ == firstZ_) {
      vertex = -2 - static_cast<std::int32_t>(bottomSlots_.size());
      bottomSlots_.push_back(key);
      bottomValues_.push_back(0.0f);
    } else if (vertex == -1) {
      const double fx = kEdgeX[edge][0] * wa + kEdgeX[edge][1] * wb;
      const double fy = kEdgeY[edge][0] * wa + kEdgeY[edge][1] * wb;
      const double fz = kEdgeZ[edge][0] * wa + kEdgeZ[edge][1] * wb;
      const double total = wa + wb;
      vertex = newVertex(static_cast<double>(x_) + step_ * fx / total,
                         static_cast<double>(y_) + step_ * fy / total,
                         static_cast<double>(z_) + step_ * fz / total);
    }
    const float sa = static_cast<float>(wa), sb = static_cast<float>(wb);
    for (int i = 0; i < 3; ++i) {
      g[0][i] = static_cast<float>(grad_[a][i] * sa);
      g[1][i] = static_cast<float>(grad_[b][i] * sb);
    }
  }
  face_[static_cast<std::size_t>(corners_++)] = vertex;
  if (corners_ == 3) {
    out_.faces.push_back(face_);
    corners_ = 0;
  }
  float& value = vertex >= 0 ? out_.values[static_cast<std::size_t>(vertex)]
                             : bottomValues_[static_cast<std::size_t>(-2 - vertex)];
  if (range_ > value) value = static_cast<float>(range_);
  if (edge != 12) {
    addGradient(vertex, g[0][0], g[0][1], g[0][2]);
    addGradient(vertex, g[1][0], g[1][1], g[1][2]);
  }
}

/// The asymptotic decider on face 1-6 (negative: inverted): whether the face's saddle joins the corners
/// of the sign of its first corner.
bool Marcher::testFace(int face) const {
  static constexpr int kFace[6][4] = {{0, 4, 5, 1}, {1, 5, 6, 2}, {2, 6, 7, 3},
                                      {3, 7, 4, 0}, {0, 3, 2, 1}, {4, 7, 6, 5}};
  const int* f = kFace[std::abs(face) - 1];
  const double a = v_[f[0]], b = v_[f[1]], c = v_[f[2]], d = v_[f[3]];
  const double det = a * c - b * d;
  if (det > -kEps && det < kEps) return face >= 0;
  return face * a * det >= 0;
}

/// For the interior test along `edge`: the crossing t on it and the bilinear values Bt, Ct, Dt of the
/// opposite parallel edges at t (At is 0 there).
double Marcher::interiorEdgeT(int edge, double& bt, double& ct, double& dt) const {
  // Per edge: its corners (p, q) and the corners of the three parallel edges, in scikit-image's order.
  static constexpr int kEdges[12][8] = {
      {0, 1, 3, 2, 7, 6, 4, 5}, {1, 2, 0, 3, 4, 7, 5, 6}, {2, 3, 1, 0, 5, 4, 6, 7}, {3, 0, 2, 1, 6, 5, 7, 4},
      {4, 5, 7, 6, 3, 2, 0, 1}, {5, 6, 4, 7, 0, 3, 1, 2}, {6, 7, 5, 4, 1, 0, 2, 3}, {7, 4, 6, 5, 2, 1, 3, 0},
      {0, 4, 3, 7, 2, 6, 1, 5}, {1, 5, 0, 4, 3, 7, 2, 6}, {2, 6, 1, 5, 0, 4, 3, 7}, {3, 7, 2, 6, 1, 5, 0, 4}};
  const int* e = kEdges[edge];
  const double t = v_[e[0]] / (v_[e[0]] - v_[e[1]] + kEps);
  bt = v_[e[2]] + (v_[e[3]] - v_[e[2]]) * t;
  ct = v_[e[4]] + (v_[e[5]] - v_[e[4]]) * t;
  dt = v_[e[6]] + (v_[e[7]] - v_[e[6]]) * t;
  return t;
}

/// Lewiner's interior test for cases 4, 6, 7, 10, 12 and 13 with the table's sign `s`.
bool Marcher::testInterior(int kase, int config, int subconfig, int s) const {
  const double* v = v_;
  double at = 0.0, bt = 0.0, ct = 0.0, dt = 0.0;
  if (kase == 4 || kase == 10) {
    const double a = (v[4] - v[0]) * (v[6] - v[2]) - (v[7] - v[3]) * (v[5] - v[1]);
    const double b =
        v[2] * (v[4] - v[0]) + v[0] * (v[6] - v[2]) - v[1] * (v[7] - v[3]) - v[3] * (v[5] - v[1]);
    const double t = -b / (2 * a + kEps);
    if (t < 0 || t > 1) return s > 0;
    at = v[0] + (v[4] - v[0]) * t;
    bt = v[3] + (v[7] - v[3]) * t;
    ct = v[2] + (v[6] - v[2]) * t;
    dt = v[1] + (v[5] - v[1]) * t;
  } else {
    const int edge = kase == 6    ? kTest6[config][2]
                     : kase == 7  ? kTest7[config][4]
                     : kase == 12 ? kTest12[config][3]
                                  : kTiling13_5_1[config][subconfig][0];
    if (edge >= 0 && edge <= 11) interiorEdgeT(edge, bt, ct, dt);  // else all 0, as scikit-image
  }
  const int test = (at >= 0 ? 1 : 0) + (bt >= 0 ? 2 : 0) + (ct >= 0 ? 4 : 0) + (dt >= 0 ? 8 : 0);
  switch (test) {
    case 5:
      return at * ct - bt * dt < kEps ? s > 0 : false;
    case 10:
      return at * ct - bt * dt >= kEps ? s > 0 : false;
    case 7:
    case 11:
    case 13:
    case 14:
    case 15:
      return s < 0;
    default:
      return s > 0;
  }
}

void Marcher::case7(int config) {
  const int sub = (testFace(kTest7[config][0]) ? 1 : 0) + (testFace(kTest7[config][1]) ? 2 : 0) +
                  (testFace(kTest7[config][2]) ? 4 : 0);
  switch (sub) {
    case 0:
      return triangles(kTiling7_1[config], 3);
    case 1:
      return triangles(kTiling7_2[config][0], 5);
    case 2:
      return triangles(kTiling7_2[config][1], 5);
    case 3:
      return triangles(kTiling7_3[config][0], 9);
    case 4:
      return triangles(kTiling7_2[config][2], 5);
    case 5:
      return triangles(kTiling7_3[config][1], 9);
    case 6:
      return triangles(kTiling7_3[config][2], 9);
    default:
      if (testInterior(7, config, sub, kTest7[config][3])) return triangles(kTiling7_4_2[config], 9);
      return triangles(kTiling7_4_1[config], 5);
  }
}

void Marcher::case10or12(int kase, int config) {
  const std::int8_t* test = kase == 10 ? kTest10[config] : kTest12[config];
  const bool first = testFace(test[0]), second = testFace(test[1]);
  if (kase == 10) {
    if (first && second) return triangles(kTiling10_1_1b[config], 4);
    if (first) return triangles(kTiling10_2[config], 8);
    if (second) return triangles(kTiling10_2b[config], 8);
    if (testInterior(10, config, 0, test[2])) return triangles(kTiling10_1_1[config], 4);
    return triangles(kTiling10_1_2[config], 8);
  }
  if (first && second) return triangles(kTiling12_1_1b[config], 4);
  if (first) return triangles(kTiling12_2[config], 8);
  if (second) return triangles(kTiling12_2b[config], 8);
  if (testInterior(12, config, 0, test[2])) return triangles(kTiling12_1_1[config], 4);
  return triangles(kTiling12_1_2[config], 8);
}

void Marcher::case13(int config) {
  int bits = 0;
  for (int f = 0; f < 6; ++f)
    if (testFace(kTest13[config][f])) bits += 1 << f;
  const int sub = kSubconfig13[bits];
  if (sub == 0) return triangles(kTiling13_1[config], 4);
  if (sub >= 1 && sub <= 6) return triangles(kTiling13_2[config][sub - 1], 6);
  if (sub >= 7 && sub <= 18) return triangles(kTiling13_3[config][sub - 7], 10);
  if (sub >= 19 && sub <= 22) return triangles(kTiling13_4[config][sub - 19], 12);
  if (sub >= 23 && sub <= 26) {
    const int s = sub - 23;
    if (testInterior(13, config, s, kTest13[config][6])) return triangles(kTiling13_5_1[config][s], 6);
    return triangles(kTiling13_5_2[config][s], 10);
  }
  if (sub >= 27 && sub <= 38) return triangles(kTiling13_3b[config][sub - 27], 10);
  if (sub >= 39 && sub <= 44) return triangles(kTiling13_2b[config][sub - 39], 6);
  if (sub == 45) return triangles(kTiling13_1b[config], 4);
}

void Marcher::lewinerCell() {
  const int kase = kCases[index_][0], config = kCases[index_][1];
  switch (kase) {
    case 1:
      return triangles(kTiling1[config], 1);
    case 2:
      return triangles(kTiling2[config], 2);
    case 3:
      return testFace(kTest3[config]) ? triangles(kTiling3_2[config], 4) : triangles(kTiling3_1[config], 2);
    case 4:
      return testInterior(4, config, 0, kTest4[config]) ? triangles(kTiling4_1[config], 2)
                                                        : triangles(kTiling4_2[config], 6);
    case 5:
      return triangles(kTiling5[config], 3);
    case 6:
      if (testFace(kTest6[config][0])) return triangles(kTiling6_2[config], 5);
      return testInterior(6, config, 0, kTest6[config][1]) ? triangles(kTiling6_1_1[config], 3)
                                                           : triangles(kTiling6_1_2[config], 9);
    case 7:
      return case7(config);
    case 8:
      return triangles(kTiling8[config], 2);
    case 9:
      return triangles(kTiling9[config], 4);
    case 10:
    case 12:
      return case10or12(kase, config);
    case 11:
      return triangles(kTiling11[config], 4);
    case 13:
      return case13(config);
    case 14:
      return triangles(kTiling14[config], 4);
    default:
      return;
  }
}

void Marcher::classicCell() {
  const std::int8_t* row = kCasesClassic[index_];
  int count = 0;
  while (3 * count < 16 && row[3 * count] != -1) ++count;
  if (count > 0) triangles(row, count);
}

/// When the output so far, scaled to the whole volume (`done` = fraction of layers walked), would not fit,
/// reserves a quarter more than that: a few reallocations instead of one per doubling, each of which copies
/// and touches fresh memory.
void Marcher::reserveFor(double done) {
  if (!(done > 0.0 && done < 1.0)) return;
  const auto grow = [done](auto& v) {
    const double projected = static_cast<double>(v.size()) / done;
    if (static_cast<double>(v.capacity()) < projected)
      v.reserve(static_cast<std::size_t>(1.25 * projected) + 256);
  };
  grow(out_.vertices);
  grow(out_.normals);
  grow(out_.values);
  grow(out_.faces);
}

/// Flips x, y, z to array axis order, normalises the normals (length in double, as scikit-image) and
/// reverses the faces for 'descent'.
void orient(LewinerMesh& mesh, bool descent) {
  for (std::size_t i = 0; i < mesh.values.size(); ++i) {
    auto& p = mesh.vertices[i];
    auto& g = mesh.normals[i];
    double length = 0.0;
    for (int a = 0; a < 3; ++a) length += static_cast<double>(g[a]) * static_cast<double>(g[a]);
    if (length > 0.0) length = 1.0 / std::pow(length, 0.5);  // as scikit-image, not sqrt
    std::swap(p[0], p[2]);
    g = {static_cast<float>(g[2] * length), static_cast<float>(g[1] * length),
         static_cast<float>(g[0] * length)};
  }
  if (descent)
    for (auto& f : mesh.faces) std::swap(f[0], f[2]);
}

/// Walks cell layers [first, last) (layer l at z = l * stepSize), as scikit-image's loop does; `done` is
/// called after each layer with the number of layers walked so far.
template <typename T>
Slab march(const StridedSamples& volume, const LewinerOptions& options, std::int64_t first, std::int64_t last,
           std::int64_t projectTo, const std::function<void(std::int64_t)>& done) {
  // scikit-image's x, y, z are array axes 2, 1, 0.
  const std::int64_t nx = volume.shape[2], ny = volume.shape[1];
  const int st = options.stepSize;
  Marcher marcher(nx, ny, st);
  if (first > 0) marcher.bottomFromBelow(first * st);
  const auto sample = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    return loadFloat32<T>(volume.at(z, y, x));
  };
  for (std::int64_t layer = first; layer < last; ++layer) {
    const std::int64_t z = layer * st;
    marcher.newLayer();
    for (std::int64_t y = 0; y + st <= ny - 1; y += st)
      for (std::int64_t x = 0; x + st <= nx - 1; x += st) {
        if (options.mask && *options.mask->at(z + st, y + st, x + st) == 0) continue;
        const float v[8] = {sample(x, y, z),
                            sample(x + st, y, z),
                            sample(x + st, y + st, z),
                            sample(x, y + st, z),
                            sample(x, y, z + st),
                            sample(x + st, y, z + st),
                            sample(x + st, y + st, z + st),
                            sample(x, y + st, z + st)};
        // Cells with all corners above the level, or none (case 0 of both tables), add nothing.
        int above = 0;
        for (float c : v) above += static_cast<double>(c) > options.level ? 1 : 0;
        if (above == 0 || above == 8) continue;
        marcher.setCell(x, y, z, v, options.level);
        options.classic ? marcher.classicCell() : marcher.lewinerCell();
      }
    marcher.reserveFor(static_cast<double>(layer + 1 - first) / static_cast<double>(projectTo));
    done(1);
  }
  return marcher.take();
}

/// Joins the slabs in order: vertex and face lists concatenated with offsets, each slab's bottom-plane
/// references resolved in the top layer of the slab below, and their gradients added after the ones from
/// below, in the serial walk's order (the float sums then equal the serial walk's). False if a reference is
/// not in the slab below (cannot happen without a mask; the caller then walks serially).
bool join(std::vector<Slab>& slabs, LewinerMesh& out) {
  std::size_t vertices = 0, faces = 0;
  for (const Slab& s : slabs) vertices += s.mesh.vertices.size(), faces += s.mesh.faces.size();
  if (vertices >= static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
    throw Error("the mesh has more vertices than int32 faces can index");
  // The first slab's arrays, reserved for the whole volume as it grew, take the others.
  out = std::move(slabs[0].mesh);
  out.vertices.reserve(vertices);
  out.normals.reserve(vertices);
  out.values.reserve(vertices);
  out.faces.reserve(faces);
  std::int32_t below = 0, offset = static_cast<std::int32_t>(out.vertices.size());
  std::vector<std::int32_t> resolved;
  for (std::size_t k = 1; k < slabs.size(); ++k) {
    Slab& s = slabs[k];
    resolved.resize(s.bottomSlots.size());
    for (std::size_t n = 0; n < s.bottomSlots.size(); ++n) {
      const auto& top = slabs[k - 1].top;
      const auto it =
          std::lower_bound(top.begin(), top.end(), std::make_pair(s.bottomSlots[n], std::int32_t{0}));
      if (it == top.end() || it->first != s.bottomSlots[n]) return false;
      resolved[n] = below + it->second;
      float& value = out.values[static_cast<std::size_t>(resolved[n])];
      value = std::max(value, s.bottomValues[n]);
    }
    for (const auto& [n, g] : s.bottomGradients) {
      auto& normal = out.normals[static_cast<std::size_t>(resolved[static_cast<std::size_t>(n)])];
      for (int a = 0; a < 3; ++a) normal[a] += g[a];
    }
    for (auto f : s.mesh.faces) {
      for (auto& v : f) v = v >= 0 ? v + offset : resolved[static_cast<std::size_t>(-2 - v)];
      out.faces.push_back(f);
    }
    out.vertices.insert(out.vertices.end(), s.mesh.vertices.begin(), s.mesh.vertices.end());
    out.normals.insert(out.normals.end(), s.mesh.normals.begin(), s.mesh.normals.end());
    out.values.insert(out.values.end(), s.mesh.values.begin(), s.mesh.values.end());
    below = offset;
    offset += static_cast<std::int32_t>(s.mesh.vertices.size());
    s.mesh = LewinerMesh();  // its top layer is needed for the next slab
    slabs[k - 1] = Slab();
  }
  return true;
}

template <typename T>
LewinerMesh marchAll(const StridedSamples& volume, const LewinerOptions& options) {
  const std::int64_t layers = (volume.shape[0] - 1) / options.stepSize;
  std::atomic<std::int64_t> walked{0};
  const auto done = [&](std::int64_t n) {
    const std::int64_t total = walked += n;
    if (options.progress) options.progress(static_cast<double>(total) / static_cast<double>(layers));
  };
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  // One slab per worker; one (the serial walk) with a mask, which can leave a shared plane's vertex to the
  // slab above. The first slab reserves its arrays for the whole volume, the others for their own layers.
  const std::int64_t slabs = options.mask ? 1 : std::min<std::int64_t>(layers / 8, arena.max_concurrency());
  LewinerMesh out;
  if (slabs > 1) {
    std::vector<Slab> parts(static_cast<std::size_t>(slabs));
    arena.execute([&] {
      tbb::parallel_for(std::int64_t{0}, slabs, [&](std::int64_t k) {
        const std::int64_t first = layers * k / slabs, last = layers * (k + 1) / slabs;
        parts[static_cast<std::size_t>(k)] =
            march<T>(volume, options, first, last, k == 0 ? layers : last - first, done);
      });
    });
    if (join(parts, out)) {
      orient(out, options.descent);
      return out;
    }
    out = LewinerMesh();
    walked = 0;
  }
  out = march<T>(volume, options, 0, layers, layers, done).mesh;
  orient(out, options.descent);
  return out;
}

}  // namespace

LewinerMesh lewinerMarchingCubes(const StridedSamples& volume, const LewinerOptions& options) {
  for (int a = 0; a < 3; ++a)
    if (volume.shape[a] < 2) throw Error("Input array must be at least 2x2x2.");
  if (!volume.data) throw Error("the volume has no data");
  if (options.stepSize < 1) throw Error("step_size must be at least one.");
  if (options.mask) {
    if (options.mask->shape != volume.shape) throw Error("volume and mask must have the same shape.");
    if (options.mask->type != ElementType::Bool && options.mask->type != ElementType::UInt8 &&
        options.mask->type != ElementType::Int8)
      throw Error("the mask must be an array of bool");
  }
  return visitElementType(volume.type, [&](auto tag) { return marchAll<decltype(tag)>(volume, options); });
}

void removeDegenerateFaces(LewinerMesh& mesh) {
  const std::size_t n = mesh.vertices.size();
  std::vector<std::int32_t> merged(n);
  for (std::size_t i = 0; i < n; ++i) merged[i] = static_cast<std::int32_t>(i);
  std::vector<char> keepFace(mesh.faces.size(), 1);
  const auto same = [&](std::int32_t a, std::int32_t b) {
    return mesh.vertices[static_cast<std::size_t>(a)] == mesh.vertices[static_cast<std::size_t>(b)];
  };
  const auto merge = [&](std::int32_t a, std::int32_t b) {
    auto &ma = merged[static_cast<std::size_t>(a)], &mb = merged[static_cast<std::size_t>(b)];
    ma = mb = std::min(ma, mb);
  };
  for (std::size_t t = 0; t < mesh.faces.size(); ++t) {
    const auto [a, b, c] = mesh.faces[t];
    if (same(a, b)) merge(a, b), keepFace[t] = 0;
    if (same(a, c)) merge(a, c), keepFace[t] = 0;
    if (same(b, c)) merge(b, c), keepFace[t] = 0;
  }
  // New index of each old vertex: the number of kept vertices up to it, minus one (as numpy's cumsum - 1).
  std::vector<std::int32_t> renumber(n);
  std::int32_t kept = 0;
  LewinerMesh out;
  for (std::size_t i = 0; i < n; ++i) {
    if (merged[i] == static_cast<std::int32_t>(i)) {
      ++kept;
      out.vertices.push_back(mesh.vertices[i]);
      out.normals.push_back(mesh.normals[i]);
      out.values.push_back(mesh.values[i]);
    }
    renumber[i] = kept - 1;
  }
  for (std::size_t t = 0; t < mesh.faces.size(); ++t) {
    if (!keepFace[t]) continue;
    std::array<std::int32_t, 3> f{};
    for (int k = 0; k < 3; ++k)
      f[k] = renumber[static_cast<std::size_t>(merged[static_cast<std::size_t>(mesh.faces[t][k])])];
    out.faces.push_back(f);
  }
  mesh = std::move(out);
}

}  // namespace cip
