#include "cip/mesh/patch_mesh.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>

#include "cip/core/error.h"
#include "cip/mesh/loop_triangulation.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/topology/cell_loops.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

using Key = std::uint64_t;
/// Centre-fan vertices live in their own key range (refined cell key * 4 + loop, with this bit set).
constexpr Key kCentreBit = Key(1) << 63;

constexpr int kOutside = -2, kEmpty = -1;

struct VertexRecord {
  Key key;
  Vec3 position;  // world
  Vec3 normal;    // world, unit
  std::uint32_t cell;
  bool unbracketed;
  bool operator<(const VertexRecord& o) const { return key < o.key; }
};

struct CellOutput {
  std::vector<VertexRecord> vertices;
  std::vector<std::array<Key, 3>> triangles;
  std::size_t refinedCells = 0, centreFans = 0;
};

/// Value and exact gradient (cell-local units) of a patch from its product terms (CornerPatch::terms), by the
/// product rule over the linear factors: the same polynomial as CornerPatch::derivatives, without its
/// Hessian.
void valueAndGradient(const CornerPatch& patch, const Vec3& x, double& value, Vec3& gradient) {
  std::array<PatchTerm, CornerPatch::kMaxTerms> terms;
  const int n = patch.terms(terms);
  std::array<double, 6> b;
  for (int f = 0; f < 6; ++f) b[f] = CornerPatch::facePlane(f, x);
  value = 0;
  gradient = Vec3::Zero();
  for (int i = 0; i < n; ++i) {
    double v = terms[i].coefficient;
    Vec3 g = Vec3::Zero();
    if (terms[i].corner >= 0) {
      const double s = patch.cornerPlane(terms[i].corner, x);
      g = v * patch.normal[terms[i].corner];
      v *= s;
    }
    for (int f = 0; f < 6; ++f) {
      if (!((terms[i].faceSquares >> f) & 1)) continue;
      // factor B_f^2: value b^2, gradient 2 b grad(B_f)
      const Vec3 a = CornerPatch::facePlaneGradient(f);
      g = g * (b[f] * b[f]) + v * (2 * b[f]) * a;
      v *= b[f] * b[f];
    }
    value += v;
    gradient += g;
  }
}

/// Sign-configuration tables used per refined cell: crossed edges, ambiguous faces, and the loops of every
/// (configuration, pairing) pair, computed once.
struct ConfigTables {
  std::array<std::uint16_t, 256> crossed;
  std::array<std::uint8_t, 256> ambiguous;
  std::vector<CellLoops> loops;  // [config * 64 + pairing]
  ConfigTables() : loops(256 * 64) {
    for (int c = 0; c < 256; ++c) {
      const auto config = static_cast<std::uint8_t>(c);
      crossed[c] = cube::crossedEdges(config);
      ambiguous[c] = 0;
      for (int f = 0; f < 6; ++f)
        if (cube::isAmbiguousFace(config, f))
          ambiguous[c] = static_cast<std::uint8_t>(ambiguous[c] | 1u << f);
      for (int p = 0; p < 64; ++p) loops[c * 64 + p] = buildCellLoops(config, static_cast<std::uint8_t>(p));
    }
  }
  static const ConfigTables& get() {
    static const ConfigTables tables;
    return tables;
  }
};

/// Per-edge data cached within one model cell.
struct EdgeData {
  bool known = false;
  double t = 0;  // crossing parameter from the edge's lower end
  Key key = 0;
};

/// Everything needed to mesh the refined cells of one model cell.
class CellMesher {
 public:
  CellMesher(const Model& model, int subdiv, std::size_t cell, const std::array<std::int64_t, 3>& refinedDims)
      : model_(model), k_(subdiv), cell_(cell), rdims_(refinedDims) {
    const auto& idx = model.cells[cell].index;
    for (int a = 0; a < 3; ++a) base_[a] = static_cast<std::int64_t>(idx[a]);
    const auto& dims = model.geometry.dims;
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const std::int64_t i = base_[0] + dx, j = base_[1] + dy, kk = base_[2] + dz;
          const int s = slotOf(dx, dy, dz);
          if (i < 0 || j < 0 || kk < 0 || i >= dims[0] - 1 || j >= dims[1] - 1 || kk >= dims[2] - 1) {
            neighbour_[s] = kOutside;
            neighbourCell_[s] = -1;
            continue;
          }
          neighbourCell_[s] =
              (dx == 0 && dy == 0 && dz == 0) ? static_cast<std::int64_t>(cell) : model.findCell(i, j, kk);
          neighbour_[s] = neighbourCell_[s] < 0 ? kEmpty : 0;
        }
    const int n = k_ + 1;
    signs_.assign(static_cast<std::size_t>(n * n * n), 0);
    edges_.assign(static_cast<std::size_t>(n * n * n * 3), EdgeData{});
    for (int z = 0; z <= k_; ++z)
      for (int y = 0; y <= k_; ++y)
        for (int x = 0; x <= k_; ++x) signs_[pointIndex(x, y, z)] = pointSign({x, y, z}) ? 1 : 0;
  }

  void run(CellOutput& out) {
    for (int z = 0; z < k_; ++z)
      for (int y = 0; y < k_; ++y)
        for (int x = 0; x < k_; ++x) refinedCell({x, y, z}, out);
  }

 private:
  static int slotOf(int dx, int dy, int dz) { return (dz + 1) * 9 + (dy + 1) * 3 + (dx + 1); }
  int pointIndex(int x, int y, int z) const { return x + (k_ + 1) * (y + (k_ + 1) * z); }

  const CornerPatch& patchOf(int slot) {
    if (!patches_[slot]) patches_[slot] = model_.patch(static_cast<std::size_t>(neighbourCell_[slot]));
    return *patches_[slot];
  }

  /// Cell-local coordinates, in the neighbour at `slot`, of the local refined point q (0..K per axis in this
  /// cell).
  Vec3 localIn(int slot, const std::array<int, 3>& q) const {
    int o[3] = {slot % 3 - 1, (slot / 3) % 3 - 1, slot / 9 - 1};
    Vec3 p;
    for (int a = 0; a < 3; ++a) p[a] = static_cast<double>(q[a] - o[a] * k_) / k_;
    return p;
  }

  /// The sign rule of patch_mesh.h for local refined point q.
  bool pointSign(const std::array<int, 3>& q) {
    int lo[3], hi[3], onPlanes = 0;
    for (int a = 0; a < 3; ++a) {
      lo[a] = q[a] == 0 ? -1 : 0;
      hi[a] = q[a] == k_ ? 1 : 0;
      onPlanes += (q[a] == 0 || q[a] == k_) ? 1 : 0;
    }
    const std::uint8_t config = model_.cells[cell_].config;
    if (onPlanes == 3) return (config >> cube::vertexIndex(q[0] / k_, q[1] / k_, q[2] / k_)) & 1;
    if (onPlanes > 0) {
      // On a grid face or edge: its grid points are corners of this cell. Without a sign change among them it
      // takes their sign.
      int v[3], mask = 0, count = 0;
      for (int a = 0; a < 3; ++a) v[a] = (q[a] == 0 || q[a] == k_) ? q[a] / k_ : -1;
      for (int corner = 0; corner < 8; ++corner) {
        auto c = cube::vertexCoords(corner);
        if ((v[0] >= 0 && c[0] != v[0]) || (v[1] >= 0 && c[1] != v[1]) || (v[2] >= 0 && c[2] != v[2]))
          continue;
        mask |= ((config >> corner) & 1) << count++;
      }
      if (mask == 0) return false;
      if (mask == (1 << count) - 1) return true;
    }
    // The patch of the lowest-index cell containing q.
    for (int dz = lo[2]; dz <= hi[2]; ++dz)
      for (int dy = lo[1]; dy <= hi[1]; ++dy)
        for (int dx = lo[0]; dx <= hi[0]; ++dx) {
          const int s = slotOf(dx, dy, dz);
          if (neighbour_[s] >= 0) return patchOf(s).value(localIn(s, q)) > 0;
        }
    return false;  // unreachable: this cell contains q
  }

  Key pointKey(const std::array<int, 3>& q) const {
    std::int64_t g[3];
    for (int a = 0; a < 3; ++a) g[a] = base_[a] * k_ + q[a];
    return static_cast<Key>(g[0] + rdims_[0] * (g[1] + rdims_[1] * g[2]));
  }

  /// The crossing on the refined edge from local point q along `axis` (signs differ), computed once per model
  /// cell.
  const EdgeData& edge(const std::array<int, 3>& q, int axis, CellOutput& out) {
    EdgeData& e = edges_[static_cast<std::size_t>(pointIndex(q[0], q[1], q[2]) * 3 + axis)];
    if (e.known) return e;
    e.known = true;
    e.key = pointKey(q) * 3 + static_cast<Key>(axis);
    // Owner: the lowest-index non-empty cell containing the whole edge.
    int lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      lo[a] = a != axis && q[a] == 0 ? -1 : 0;
      hi[a] = a != axis && q[a] == k_ ? 1 : 0;
    }
    int owner = -1;
    for (int dz = lo[2]; dz <= hi[2] && owner < 0; ++dz)
      for (int dy = lo[1]; dy <= hi[1] && owner < 0; ++dy)
        for (int dx = lo[0]; dx <= hi[0] && owner < 0; ++dx)
          if (neighbour_[slotOf(dx, dy, dz)] >= 0) owner = slotOf(dx, dy, dz);
    auto q1 = q;
    q1[axis] += 1;
    const bool s0 = signs_[pointIndex(q[0], q[1], q[2])] != 0,
               s1 = signs_[pointIndex(q1[0], q1[1], q1[2])] != 0;
    const CornerPatch& patch = patchOf(owner);
    const Vec3 p0 = localIn(owner, q), p1 = localIn(owner, q1);
    auto f = [&](double t) { return patch.value(p0 + t * (p1 - p0)); };
    double a = 0, b = 1, fa = f(0), fb = f(1);
    bool bracketed = (fa > 0) == s0 && (fb > 0) == s1;
    if (!bracketed) {
      // The first sign change of the patch along the edge; without one, the end whose assigned sign the patch
      // contradicts (the patch leaves the cell there and the mesh closes it in the face).
      constexpr int kSamples = 16;
      double prevT = 0, prevF = fa;
      for (int i = 1; i <= kSamples && !bracketed; ++i) {
        double t = static_cast<double>(i) / kSamples, ft = f(t);
        if ((ft > 0) != (prevF > 0)) {
          a = prevT;
          fa = prevF;
          b = t;
          fb = ft;
          bracketed = true;
        }
        prevT = t;
        prevF = ft;
      }
      if (!bracketed) {
        e.t = (fa > 0) != s0 ? 0.0 : 1.0;
        emitEdgeVertex(e, owner, p0, p1, s0, out, true);
        return e;
      }
    }
    // Illinois regula falsi on [a,b] with fa, fb of opposite signs (fa > 0 or fb > 0, not both).
    int side = 0;
    for (int it = 0; it < 100 && b - a > 1e-15; ++it) {
      double c = (fa * b - fb * a) / (fa - fb);
      if (!(c > a && c < b)) c = 0.5 * (a + b);
      double fc = f(c);
      if (fc == 0) {
        a = b = c;
        break;
      }
      if ((fc > 0) == (fa > 0)) {
        a = c;
        fa = fc;
        if (side == -1) fb *= 0.5;
        side = -1;
      } else {
        b = c;
        fb = fc;
        if (side == 1) fa *= 0.5;
        side = 1;
      }
    }
    e.t = std::abs(fa) <= std::abs(fb) ? a : b;
    emitEdgeVertex(e, owner, p0, p1, s0, out, false);
    return e;
  }

  /// The patch gradient at `x` (cell-local). Where it vanishes (at a cell corner whose three faces are all
  /// bounding planes the patch has a singular zero), the gradient slightly towards the cell centre; zero if
  /// that vanishes too.
  static Vec3 patchNormal(const CornerPatch& patch, const Vec3& x) {
    double value;
    Vec3 g;
    valueAndGradient(patch, x, value, g);
    const double tiny = 1e-12;
    for (double step : {1e-4, 1e-2}) {
      if (g.allFinite() && g.norm() > tiny) return g;
      valueAndGradient(patch, x + step * (Vec3(0.5, 0.5, 0.5) - x), value, g);
    }
    return g.allFinite() && g.norm() > tiny ? g : Vec3::Zero();
  }

  void emitEdgeVertex(const EdgeData& e, int owner, const Vec3& p0, const Vec3& p1, bool s0, CellOutput& out,
                      bool unbracketed) {
    const CornerPatch& patch = patchOf(owner);
    const Vec3 local = p0 + e.t * (p1 - p0);
    const std::size_t ownerCell = static_cast<std::size_t>(neighbourCell_[owner]);
    Vec3 grad = patchNormal(patch, local);
    if (!(grad.norm() > 0)) grad = (p1 - p0) * (s0 ? -1.0 : 1.0);
    const GridGeometry& geo = model_.geometry;
    out.vertices.push_back(VertexRecord{e.key, geo.indexToWorld(model_.cellOrigin(ownerCell) + local),
                                        indexNormalToWorld(grad, geo.spacing),
                                        static_cast<std::uint32_t>(ownerCell), unbracketed});
  }

  void refinedCell(const std::array<int, 3>& r, CellOutput& out) {
    std::uint8_t config = 0;
    for (int v = 0; v < 8; ++v) {
      auto c = cube::vertexCoords(v);
      if (signs_[pointIndex(r[0] + c[0], r[1] + c[1], r[2] + c[2])])
        config = static_cast<std::uint8_t>(config | 1u << v);
    }
    if (config == 0 || config == 0xFF) return;
    ++out.refinedCells;
    const ConfigTables& tables = ConfigTables::get();
    const std::uint16_t crossed = tables.crossed[config];
    std::array<const EdgeData*, 12> ed{};
    for (int e = 0; e < 12; ++e) {
      if (!((crossed >> e) & 1)) continue;
      auto c = cube::vertexCoords(cube::edgeVertex(e, 0));
      ed[e] = &edge({r[0] + c[0], r[1] + c[1], r[2] + c[2]}, cube::edgeAxis(e), out);
    }
    std::uint8_t pairing = 0;
    for (int f = 0; f < 6; ++f) {
      if (!((tables.ambiguous[config] >> f) & 1)) continue;
      std::array<double, 4> t;
      for (int k = 0; k < 4; ++k) t[k] = ed[cube::faceEdge(f, k)]->t;
      if (cutsOffDiagonal03(t, (config >> cube::faceVertex(f, 0)) & 1))
        pairing = static_cast<std::uint8_t>(pairing | 1u << f);
    }
    // Pairing bits of faces that are not ambiguous are ignored by buildCellLoops, so they are always 0 here.
    const CellLoops& loops = tables.loops[config * 64 + pairing];
    int start = 0;
    for (int l = 0; l < loops.numLoops; ++l) {
      const int n = loops.loopSize[l];
      std::array<Vec3, 12> local;  // refined-cell-local
      std::array<Key, 13> keys;
      for (int k = 0; k < n; ++k) {
        int e = loops.edges[start + k];
        auto c = cube::vertexCoords(cube::edgeVertex(e, 0));
        local[k] = Vec3(c[0], c[1], c[2]);
        local[k][cube::edgeAxis(e)] = ed[e]->t;
        keys[k] = ed[e]->key;
      }
      LoopTriangles tri = triangulateLoop(n, &loops.edges[start], local.data());
      if (tri.kind == LoopTriangulation::CentreFan) {
        ++out.centreFans;
        keys[n] = kCentreBit | (pointKey(r) * 4 + static_cast<Key>(l));
        out.vertices.push_back(centreVertex(r, local, n, keys[n]));
      }
      for (int k = 0; k < tri.count; ++k) {
        const auto& t = tri.triangles[k];
        out.triangles.push_back({keys[t[0]], keys[t[1]], keys[t[2]]});
      }
      start += n;
    }
  }

  /// The loop corners' mean, moved onto this cell's patch by a few Newton steps if they converge inside the
  /// refined cell.
  VertexRecord centreVertex(const std::array<int, 3>& r, const std::array<Vec3, 12>& local, int n, Key key) {
    Vec3 m = Vec3::Zero();
    for (int k = 0; k < n; ++k) m += local[k];
    m /= n;
    const Vec3 corner(r[0], r[1], r[2]);
    const CornerPatch& patch = patchOf(slotOf(0, 0, 0));
    Vec3 x = (corner + m) / k_;  // model-cell-local
    Vec3 start = x;
    for (int it = 0; it < 8; ++it) {
      double value;
      Vec3 gradient;
      valueAndGradient(patch, x, value, gradient);
      double g2 = gradient.squaredNorm();
      if (!(g2 > 0)) break;
      x -= value / g2 * gradient;
    }
    Vec3 rel = x * k_ - corner;
    if (!x.allFinite() || rel.minCoeff() < 0 || rel.maxCoeff() > 1) x = start;
    Vec3 grad = patchNormal(patch, x);
    const GridGeometry& geo = model_.geometry;
    return VertexRecord{
        key, geo.indexToWorld(model_.cellOrigin(cell_) + x),
        indexNormalToWorld(grad.allFinite() && grad.norm() > 0 ? grad : Vec3::UnitZ(), geo.spacing),
        static_cast<std::uint32_t>(cell_), false};
  }

  const Model& model_;
  const int k_;
  const std::size_t cell_;
  const std::array<std::int64_t, 3> rdims_;
  std::array<std::int64_t, 3> base_{};
  std::array<int, 27> neighbour_{};  // kOutside, kEmpty, or 0 (non-empty)
  std::array<std::int64_t, 27> neighbourCell_{};
  std::array<std::optional<CornerPatch>, 27> patches_;
  std::vector<std::uint8_t> signs_;
  std::vector<EdgeData> edges_;
};

}  // namespace

TriangleMesh patchMesh(const Model& model, int subdiv, const PatchMeshOptions& options,
                       PatchMeshStats* stats) {
  if (subdiv < 1 || subdiv > 64)
    throw Error("patch mesh: subdivision must be between 1 and 64, not " + std::to_string(subdiv));
  const auto& dims = model.geometry.dims;
  std::array<std::int64_t, 3> rdims;
  for (int a = 0; a < 3; ++a) {
    if (dims[a] < 2 && !model.cells.empty()) throw Error("patch mesh: the model's grid has no cells");
    rdims[a] = std::max<std::int64_t>(1, (dims[a] - 1) * subdiv + 1);
  }
  // Keys: refined point index * 3 + axis (and * 4 + loop for centres) must stay below the centre bit.
  const double keySpace =
      static_cast<double>(rdims[0]) * static_cast<double>(rdims[1]) * static_cast<double>(rdims[2]);
  if (keySpace * 4 >= static_cast<double>(kCentreBit)) throw Error("patch mesh: refined grid too large");
  const std::size_t numCells = model.cells.size();
  std::vector<CellOutput> outputs(numCells);
  TriangleMesh mesh;
  PatchMeshStats s;
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numCells, 16),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t c = r.begin(); c != r.end(); ++c) {
                          CellMesher mesher(model, subdiv, c, rdims);
                          mesher.run(outputs[c]);
                        }
                      });
    // Unique vertices by key (duplicates from neighbouring cells are identical: computed from the same data).
    std::vector<VertexRecord> all;
    std::size_t total = 0, triangles = 0;
    for (const auto& o : outputs) {
      total += o.vertices.size();
      triangles += o.triangles.size();
      s.refinedCells += o.refinedCells;
      s.centreFans += o.centreFans;
    }
    all.reserve(total);
    for (const auto& o : outputs) all.insert(all.end(), o.vertices.begin(), o.vertices.end());
    tbb::parallel_sort(all.begin(), all.end());
    all.erase(std::unique(all.begin(), all.end(),
                          [](const VertexRecord& a, const VertexRecord& b) { return a.key == b.key; }),
              all.end());
    if (all.size() > std::numeric_limits<std::uint32_t>::max()) throw Error("patch mesh: too many vertices");
    mesh.positions.resize(all.size());
    mesh.normals.resize(all.size());
    mesh.vertexCell.resize(all.size());
    for (std::size_t v = 0; v < all.size(); ++v) {
      mesh.positions[v] = all[v].position;
      mesh.normals[v] = all[v].normal;
      mesh.vertexCell[v] = all[v].cell;
      if (!(all[v].key & kCentreBit)) ++s.edgeVertices;
      if (all[v].unbracketed) ++s.unbracketedEdges;
    }
    std::vector<std::size_t> triOffset(numCells + 1, 0);
    for (std::size_t c = 0; c < numCells; ++c) triOffset[c + 1] = triOffset[c] + outputs[c].triangles.size();
    mesh.triangles.resize(triangles);
    mesh.triangleCell.resize(triangles);
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, numCells, 64), [&](const tbb::blocked_range<std::size_t>& r) {
          for (std::size_t c = r.begin(); c != r.end(); ++c) {
            std::size_t t = triOffset[c];
            for (const auto& keys : outputs[c].triangles) {
              for (int k = 0; k < 3; ++k) {
                auto it = std::lower_bound(all.begin(), all.end(), keys[k],
                                           [](const VertexRecord& v, Key key) { return v.key < key; });
                mesh.triangles[t][k] = static_cast<std::uint32_t>(it - all.begin());
              }
              mesh.triangleCell[t] = static_cast<std::uint32_t>(c);
              ++t;
            }
          }
        });
  });
  if (stats) *stats = s;
  return mesh;
}

}  // namespace cip
