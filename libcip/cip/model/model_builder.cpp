#include "cip/model/model_builder.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <cmath>
#include <mutex>

#include "cip/core/bisection.h"
#include "cip/core/error.h"
#include "cip/model/patch_fitting.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/reference/point_hermite.h"
#include "cip/reference/point_hermite_table.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

using Key = std::uint64_t;

struct EdgeRef {
  Key key;
  std::uint32_t brick;
  bool operator<(const EdgeRef& o) const { return key != o.key ? key < o.key : brick < o.brick; }
};

struct CellRef {
  Key key;
  std::uint32_t brick;
  std::uint8_t config;
  bool operator<(const CellRef& o) const { return key < o.key; }
};

struct Indexer {
  std::array<std::int64_t, 3> dims;
  Key point(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return static_cast<Key>(i + dims[0] * (j + dims[1] * k));
  }
  std::array<std::int64_t, 3> coords(Key p) const {
    std::int64_t v = static_cast<std::int64_t>(p);
    return {v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])};
  }
};

Vec3 axisVector(int axis) {
  return Vec3::Unit(axis);
}

/// Central-difference gradient (index space) at a brick-local grid point; one-sided at the brick border.
Vec3 gridGradient(const DenseGrid& g, std::int64_t i, std::int64_t j, std::int64_t k) {
  Vec3 grad;
  std::array<std::int64_t, 3> p{i, j, k};
  for (int a = 0; a < 3; ++a) {
    auto lo = p, hi = p;
    if (p[a] > 0) lo[a] -= 1;
    if (p[a] + 1 < g.geometry.dims[a]) hi[a] += 1;
    double span = static_cast<double>(hi[a] - lo[a]);
    grad[a] = span > 0 ? (g.at(hi[0], hi[1], hi[2]) - g.at(lo[0], lo[1], lo[2])) / span : 0.0;
  }
  return grad;
}

std::uint8_t cellConfig(const DenseGrid& g, std::int64_t i, std::int64_t j, std::int64_t k, double iso,
                        bool& nonFinite) {
  std::uint8_t config = 0;
  nonFinite = false;
  for (int v = 0; v < 8; ++v) {
    auto c = cube::vertexCoords(v);
    double x = g.at(i + c[0], j + c[1], k + c[2]);
    if (!std::isfinite(x)) nonFinite = true;
    if (x > iso) config = static_cast<std::uint8_t>(config | (1u << v));
  }
  return config;
}

/// Reference surface point inside a cell for CentralRule::Interior, or false.
bool interiorPoint(const CornerPatch& patch, const std::function<double(const Vec3&)>& ref, Vec3& out) {
  Vec3 dir = Vec3::Zero();
  for (int c = 0; c < patch.numCorners; ++c) dir += patch.normal[c];
  if (!(dir.norm() > 1e-12)) return false;
  dir.normalize();
  const Vec3 centre(0.5, 0.5, 0.5);
  // Clip the line centre + s*dir to the cell, shrunk by a margin so the point is strictly interior.
  const double margin = 1e-3;
  double smin = -1e9, smax = 1e9;
  for (int a = 0; a < 3; ++a) {
    if (std::abs(dir[a]) < 1e-15) continue;
    double s0 = (margin - 0.5) / dir[a], s1 = (1 - margin - 0.5) / dir[a];
    smin = std::max(smin, std::min(s0, s1));
    smax = std::min(smax, std::max(s0, s1));
  }
  constexpr int kSteps = 16;
  double best = 1e9;
  bool found = false;
  double prevS = smin, prevF = ref(centre + smin * dir);
  for (int s = 1; s <= kSteps; ++s) {
    double cs = smin + (smax - smin) * s / kSteps, cf = ref(centre + cs * dir);
    if ((prevF > 0) != (cf > 0)) {
      double root =
          bisectSignChange([&](double along) { return ref(centre + along * dir); }, prevS, cs, prevF);
      if (std::abs(root) < best) {
        best = std::abs(root);
        out = centre + root * dir;
        found = true;
      }
    }
    prevS = cs;
    prevF = cf;
  }
  return found;
}

class ProgressReporter {
 public:
  explicit ProgressReporter(const std::function<void(double)>& fn) : fn_(fn) {}
  void set(double fraction) {
    if (!fn_) return;
    std::lock_guard<std::mutex> lock(mutex_);
    if (fraction < last_ + 0.005 && fraction < 1.0) return;
    last_ = fraction;
    fn_(fraction);
  }

 private:
  const std::function<void(double)>& fn_;
  std::mutex mutex_;
  double last_ = -1;
};

}  // namespace

CornerPatch buildCellPatch(std::uint8_t config, const std::array<IsoVertex, 12>& vertexData,
                           std::uint8_t* pairing03Out, CellLoops* loopsOut, bool fitCoefficients) {
  std::uint8_t pairing = 0;
  for (int f = 0; f < 6; ++f) {
    if (!cube::isAmbiguousFace(config, f)) continue;
    std::array<double, 4> t;
    for (int k = 0; k < 4; ++k) {
      int e = cube::faceEdge(f, k);
      t[k] = vertexData[e].position[cube::edgeAxis(e)];
    }
    bool v0Positive = (config >> cube::faceVertex(f, 0)) & 1;
    if (cutsOffDiagonal03(t, v0Positive)) pairing = static_cast<std::uint8_t>(pairing | (1u << f));
  }
  CellLoops loops = buildCellLoops(config, pairing);
  CornerPatch patch;
  patch.numCorners = loops.numCorners();
  for (int c = 0; c < patch.numCorners; ++c) {
    const IsoVertex& v = vertexData[loops.edges[c]];
    patch.point[c] = v.position;
    patch.normal[c] = v.normal;
    patch.weight[c] = v.weight;
    patch.edge[c] = loops.edges[c];
  }
  patch.faceMask = loops.faceMask;
  for (int f = 0; f < 6 && fitCoefficients; ++f)
    if ((loops.faceMask >> f) & 1)
      patch.faceCoefficient[f] = fitFaceCoefficient(faceCrossingsOf(patch, f, (pairing >> f) & 1));
  if (pairing03Out) *pairing03Out = pairing;
  if (loopsOut) *loopsOut = loops;
  return patch;
}

int brickApron(const BuildOptions& options) {
  if (options.method == PatchMethod::Fitted && options.normals != NormalMode::Exact)
    return referenceReach(options.reconstruction);
  return 1;
}

Model buildModel(const DenseGrid& grid, const BuildOptions& options) {
  GridBrick brick;
  brick.grid = &grid;
  for (int a = 0; a < 3; ++a) brick.cellEnd[a] = std::max<std::int64_t>(0, grid.geometry.dims[a] - 1);
  return buildModel(grid.geometry, {brick}, options, grid.description);
}

Model buildModel(const GridGeometry& geometry, const std::vector<GridBrick>& bricks,
                 const BuildOptions& options, const std::string& source) {
  if (options.normals == NormalMode::Exact && !options.exactField) {
    throw Error("exact normals need an analytic field; sampled volumes take gradient or edge normals");
  }
  const double iso = options.isovalue;
  const Indexer global{geometry.dims};
  ProgressReporter progress(options.progress);
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  Model model;
  model.geometry = geometry;
  model.isovalue = iso;
  model.normalMode = options.normals;
  model.method = options.method;
  model.source = source;

  arena.execute([&] {
    // Phase A: non-empty cells and their crossed edges, per brick row (deterministic concatenation).
    std::vector<CellRef> cells;
    std::vector<EdgeRef> edges;
    std::atomic<std::int64_t> rowsDone{0};
    std::int64_t totalRows = 0;
    for (const auto& b : bricks)
      totalRows += std::max<std::int64_t>(0, b.cellEnd[1] - b.cellBegin[1]) *
                   std::max<std::int64_t>(0, b.cellEnd[2] - b.cellBegin[2]);
    std::atomic<bool> badValue{false};
    std::array<std::int64_t, 3> badAt{};
    std::mutex badMutex;
    for (std::uint32_t bi = 0; bi < bricks.size(); ++bi) {
      const GridBrick& b = bricks[bi];
      const DenseGrid& g = *b.grid;
      std::int64_t ny = b.cellEnd[1] - b.cellBegin[1], nz = b.cellEnd[2] - b.cellBegin[2];
      if (ny <= 0 || nz <= 0 || b.cellEnd[0] <= b.cellBegin[0]) continue;
      std::vector<std::vector<CellRef>> rowCells(static_cast<std::size_t>(ny * nz));
      std::vector<std::vector<EdgeRef>> rowEdges(rowCells.size());
      tbb::parallel_for(
          tbb::blocked_range<std::int64_t>(0, ny * nz), [&](const tbb::blocked_range<std::int64_t>& r) {
            for (std::int64_t row = r.begin(); row != r.end(); ++row) {
              std::int64_t j = b.cellBegin[1] + row % ny, k = b.cellBegin[2] + row / ny;
              auto& rc = rowCells[row];
              auto& re = rowEdges[row];
              for (std::int64_t i = b.cellBegin[0]; i < b.cellEnd[0]; ++i) {
                bool nonFinite;
                std::uint8_t config = cellConfig(g, i, j, k, iso, nonFinite);
                if (nonFinite) {
                  if (!options.skipNonFinite) {
                    std::lock_guard<std::mutex> lock(badMutex);
                    if (!badValue) badAt = {i + b.offset[0], j + b.offset[1], k + b.offset[2]};
                    badValue = true;
                  }
                  continue;
                }
                if (config == 0 || config == 0xFF) continue;
                std::int64_t gi = i + b.offset[0], gj = j + b.offset[1], gk = k + b.offset[2];
                rc.push_back(CellRef{global.point(gi, gj, gk), bi, config});
                std::uint16_t crossed = cube::crossedEdges(config);
                for (int e = 0; e < 12; ++e) {
                  if (!((crossed >> e) & 1)) continue;
                  auto c = cube::vertexCoords(cube::edgeVertex(e, 0));
                  re.push_back(
                      EdgeRef{global.point(gi + c[0], gj + c[1], gk + c[2]) * 3 + cube::edgeAxis(e), bi});
                }
              }
              std::sort(re.begin(), re.end());
              re.erase(std::unique(re.begin(), re.end(), [](auto& x, auto& y) { return x.key == y.key; }),
                       re.end());
              progress.set(0.3 * static_cast<double>(++rowsDone) / static_cast<double>(totalRows));
            }
          });
      for (auto& rc : rowCells) cells.insert(cells.end(), rc.begin(), rc.end());
      for (auto& re : rowEdges) edges.insert(edges.end(), re.begin(), re.end());
    }
    if (badValue) {
      throw NonFiniteSampleError("NaN or infinite voxel value in cell (" + std::to_string(badAt[0]) + "," +
                                     std::to_string(badAt[1]) + "," + std::to_string(badAt[2]) + ")",
                                 {badAt[0], badAt[1], badAt[2]});
    }
    // The reconstruction of the reference of the samples (the fitted construction, unless exact), Auto
    // resolved from the crossed cells in their deterministic order.
    const bool sampledReference =
        options.method == PatchMethod::Fitted && options.normals != NormalMode::Exact;
    Reconstruction kind = options.reconstruction;
    SamplingEstimate sampling;
    if (sampledReference && kind == Reconstruction::Auto) {
      SamplingEstimator estimator;
      for (const CellRef& c : cells) {
        const GridBrick& b = bricks[c.brick];
        const auto gc = global.coords(c.key);
        estimator.addCell(*b.grid, {gc[0] - b.offset[0], gc[1] - b.offset[1], gc[2] - b.offset[2]});
      }
      sampling = estimator.estimate();
      kind = chooseReconstruction(sampling);
    }
    // The reference's data at the corners of the crossed cells, once per grid point, per brick.
    std::vector<PointHermiteTable> tables(sampledReference ? bricks.size() : 0);
    if (sampledReference) {
      std::vector<std::vector<std::int64_t>> brickCells(bricks.size());
      for (const CellRef& c : cells) {
        const GridBrick& b = bricks[c.brick];
        const auto gc = global.coords(c.key);
        brickCells[c.brick].push_back(
            b.grid->index(gc[0] - b.offset[0], gc[1] - b.offset[1], gc[2] - b.offset[2]));
      }
      tbb::parallel_for(std::size_t(0), bricks.size(), [&](std::size_t bi) {
        if (!brickCells[bi].empty()) tables[bi] = PointHermiteTable(*bricks[bi].grid, brickCells[bi], kind);
      });
    }
    // Phase B: unique isovertices, ordered by edge key; each computed from the first brick that has its edge.
    tbb::parallel_sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end(), [](auto& x, auto& y) { return x.key == y.key; }),
                edges.end());
    if (edges.size() > std::numeric_limits<std::uint32_t>::max())
      throw Error("too many isovertices for one model");
    model.vertices.resize(edges.size());
    const Vec3 spacing = geometry.spacing;
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, edges.size()), [&](const tbb::blocked_range<std::size_t>& r) {
          for (std::size_t n = r.begin(); n != r.end(); ++n) {
            const GridBrick& b = bricks[edges[n].brick];
            const DenseGrid& g = *b.grid;
            int axis = static_cast<int>(edges[n].key % 3);
            auto gp = global.coords(edges[n].key / 3);
            std::array<std::int64_t, 3> lp{gp[0] - b.offset[0], gp[1] - b.offset[1], gp[2] - b.offset[2]};
            auto lq = lp;
            lq[axis] += 1;
            double v0 = g.at(lp[0], lp[1], lp[2]), v1 = g.at(lq[0], lq[1], lq[2]);
            Vec3 towardsPositive = axisVector(axis) * (v1 > iso ? 1.0 : -1.0);
            Vec3 start(static_cast<double>(gp[0]), static_cast<double>(gp[1]), static_cast<double>(gp[2]));
            IsoVertex& vx = model.vertices[n];
            double t;
            if (options.normals == NormalMode::Exact) {
              Vec3 wa = geometry.indexToWorld(start), wb = geometry.indexToWorld(start + axisVector(axis));
              t = exactCrossing(*options.exactField, wa, wb, iso);
              Vec3 gradWorld = options.exactField->gradient(wa + t * (wb - wa));
              vx.normal = orientCornerNormal(gradWorld.cwiseProduct(spacing), towardsPositive);
            } else {
              t = linearCrossing(v0, v1, iso);
              if (options.method == PatchMethod::Fitted && options.normals == NormalMode::Gradient) {
                const PointHermiteTable& table = tables[edges[n].brick];
                t = cubicEdgeVertex(table.at(g.index(lp[0], lp[1], lp[2])),
                                    table.at(g.index(lq[0], lq[1], lq[2])), axis, iso, vx.normal);
                if (v0 == iso || v1 == iso)  // on a grid point: see normalClearOfUncrossedEdges
                  vx.normal = normalClearOfUncrossedEdges(g, v0 == iso ? lp : lq, axis, iso, vx.normal,
                                                          towardsPositive);
              } else if (options.normals == NormalMode::Edge) {
                vx.normal = towardsPositive;
              } else {
                Vec3 g0 = gridGradient(g, lp[0], lp[1], lp[2]), g1 = gridGradient(g, lq[0], lq[1], lq[2]);
                vx.normal = orientCornerNormal((1 - t) * g0 + t * g1, towardsPositive);
              }
            }
            vx.position = start;
            vx.position[axis] += t;
            vx.weight = 1.0;
          }
        });
    progress.set(0.5);
    // Phase C: cell patches, in cell-key order.
    std::stable_sort(cells.begin(), cells.end());
    model.cells.resize(cells.size());
    std::uint64_t cornerTotal = 0;
    for (std::size_t c = 0; c < cells.size(); ++c) {
      model.cells[c].firstCorner = static_cast<std::uint32_t>(cornerTotal);
      cornerTotal += static_cast<std::uint64_t>(__builtin_popcount(cube::crossedEdges(cells[c].config)));
      if (cornerTotal > std::numeric_limits<std::uint32_t>::max())
        throw Error("too many corners for one model");
    }
    model.corners.resize(cornerTotal);
    // The fitted construction works on the loops again; they are kept rather than rebuilt.
    const bool fitted = options.fitCoefficients && options.method == PatchMethod::Fitted;
    std::vector<CellLoops> cellLoops(fitted ? cells.size() : 0);
    std::atomic<std::size_t> cellsDone{0};
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, cells.size(), 256), [&](const tbb::blocked_range<std::size_t>& r) {
          for (std::size_t c = r.begin(); c != r.end(); ++c) {
            const CellRef& ref = cells[c];
            auto gc = global.coords(ref.key);
            Vec3 origin(static_cast<double>(gc[0]), static_cast<double>(gc[1]), static_cast<double>(gc[2]));
            std::array<IsoVertex, 12> local;
            std::array<std::uint32_t, 12> vertexIndex{};
            std::uint16_t crossed = cube::crossedEdges(ref.config);
            for (int e = 0; e < 12; ++e) {
              if (!((crossed >> e) & 1)) continue;
              auto vc = cube::vertexCoords(cube::edgeVertex(e, 0));
              Key key = global.point(gc[0] + vc[0], gc[1] + vc[1], gc[2] + vc[2]) * 3 + cube::edgeAxis(e);
              auto it = std::lower_bound(edges.begin(), edges.end(), key,
                                         [](const EdgeRef& x, Key k) { return x.key < k; });
              vertexIndex[e] = static_cast<std::uint32_t>(it - edges.begin());
              local[e] = model.vertices[vertexIndex[e]];
              local[e].position -= origin;
            }
            ModelCell& mc = model.cells[c];
            CellLoops loops;
            // PatchMethod::Fitted replaces the coefficients afterwards (fitModelPatches).
            const bool paperCoefficients = options.fitCoefficients && options.method == PatchMethod::Paper;
            CornerPatch patch = buildCellPatch(ref.config, local, &mc.pairing03, &loops, paperCoefficients);
            if (paperCoefficients && options.central == CentralRule::Interior) {
              Vec3 p;
              std::function<double(const Vec3&)> reference;
              if (options.exactField) {
                reference = [&](const Vec3& x) {
                  return options.exactField->value(geometry.indexToWorld(origin + x)) - iso;
                };
              } else {
                const GridBrick& b = bricks[ref.brick];
                std::array<double, 8> v;
                for (int k = 0; k < 8; ++k) {
                  auto vc = cube::vertexCoords(k);
                  v[k] = b.grid->at(gc[0] - b.offset[0] + vc[0], gc[1] - b.offset[1] + vc[1],
                                    gc[2] - b.offset[2] + vc[2]);
                }
                reference = [v, iso](const Vec3& x) {
                  double sum = 0;
                  for (int k = 0; k < 8; ++k) {
                    auto vc = cube::vertexCoords(k);
                    sum += v[k] * (vc[0] ? x[0] : 1 - x[0]) * (vc[1] ? x[1] : 1 - x[1]) *
                           (vc[2] ? x[2] : 1 - x[2]);
                  }
                  return sum - iso;
                };
              }
              if (interiorPoint(patch, reference, p)) patch.central = fitCentralCoefficient(patch, p);
            }
            mc.index = {static_cast<std::uint32_t>(gc[0]), static_cast<std::uint32_t>(gc[1]),
                        static_cast<std::uint32_t>(gc[2])};
            mc.config = ref.config;
            mc.numLoops = static_cast<std::uint8_t>(loops.numLoops);
            mc.loopSize = loops.loopSize;
            mc.faceCoefficient = patch.faceCoefficient;
            mc.central = patch.central;
            for (int k = 0; k < patch.numCorners; ++k)
              model.corners[mc.firstCorner + k] = vertexIndex[loops.edges[k]];
            if (fitted) cellLoops[c] = loops;
            std::size_t done = ++cellsDone;
            if (done % 4096 == 0)
              progress.set(0.5 + 0.5 * static_cast<double>(done) / static_cast<double>(cells.size()));
          }
        });
    if (fitted) {
      // Reference: the analytic field in exact mode, else the tricubic interpolant of the cell's brick.
      const Vec3 metric = Vec3::Constant(spacing.minCoeff()).cwiseQuotient(spacing);
      FittingStats stats = fitModelPatches(model, cellLoops, [&](std::size_t c, CellReference& ref) {
        const auto& index = model.cells[c].index;  // as global.coords(cells[c].key), without divisions
        const std::array<std::int64_t, 3> gc{index[0], index[1], index[2]};
        if (options.normals == NormalMode::Exact) {
          ref = CellReference();
          ref.field = options.exactField;
          ref.geometry = &model.geometry;
          ref.origin =
              Vec3(static_cast<double>(gc[0]), static_cast<double>(gc[1]), static_cast<double>(gc[2]));
          ref.isovalue = iso;
        } else {
          const GridBrick& b = bricks[cells[c].brick];
          tables[cells[c].brick].setReference({gc[0] - b.offset[0], gc[1] - b.offset[1], gc[2] - b.offset[2]},
                                              iso, ref);
        }
        ref.metric = metric;
      });
      if (sampledReference) {
        model.reconstruction = kind;
        stats.reconstruction = kind;
        stats.sampling = sampling;
      }
      if (options.fittingStats) *options.fittingStats = stats;
    }
  });
  progress.set(1.0);
  return model;
}

}  // namespace cip
