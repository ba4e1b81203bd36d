#include "cip/model/build_passes.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>

#include "cip/core/bisection.h"
#include "cip/core/error.h"
#include "cip/core/huge_pages.h"
#include "cip/model/patch_fitting.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/topology/cube_topology.h"

namespace cip::build {

/// Where the fitted construction's coefficients start in BuildOptions::progress (they take most of its time).
constexpr double kFitProgress = 0.6;

Key GridKeys::cellEdge(const std::array<std::int64_t, 3>& cell, int e) const {
  auto c = cube::vertexCoords(cube::edgeVertex(e, 0));
  return point(cell[0] + c[0], cell[1] + c[1], cell[2] + c[2]) * 3 + cube::edgeAxis(e);
}

MaskRule maskRule(const BuildOptions& options) {
  const bool sampled = options.method == PatchMethod::Fitted && options.normals != NormalMode::Exact;
  const bool asked = options.label || options.reconstruction == Reconstruction::Mask;
  if (asked && !sampled)
    throw Error(
        "the mask reference (labels, reconstruction mask) needs the fitted method with gradient or edge "
        "normals");
  if (asked) return MaskRule::Mask;
  if (!sampled || options.reconstruction != Reconstruction::Auto || options.exactField)
    return MaskRule::Samples;
  return MaskRule::Detect;
}

DenseGrid maskField(const DenseGrid& samples, const BuildOptions& options, std::int64_t firstSliceZ) {
  if (!options.label) return smoothMask(samples, options.isovalue);
  return smoothLabel(samples, *options.label, firstSliceZ);
}

BuildOptions maskFieldOptions(const BuildOptions& options) {
  BuildOptions o = options;
  o.reconstruction = Reconstruction::Central8;
  o.label.reset();
  if (options.label) o.isovalue = 0;
  return o;
}

std::array<std::int64_t, 3> localPoint(const GridBrick& brick, const std::array<std::int64_t, 3>& global) {
  return {global[0] - brick.offset[0], global[1] - brick.offset[1], global[2] - brick.offset[2]};
}

namespace {

bool sameKey(const EdgeRef& x, const EdgeRef& y) {
  return x.key == y.key;
}

// ---- Pass 1: scan ----

/// Rows per task of the scan's parallel loops (the cells' rows and, in brickEdges, the points' rows).
constexpr std::int64_t kRowChunk = 64;

/// The first cell the scan's workers found with a non-finite corner value.
struct NonFiniteCell {
  std::atomic<bool> found{false};
  std::array<std::int64_t, 3> at{};
  std::mutex mutex;

  void report(const std::array<std::int64_t, 3>& cell) {
    std::lock_guard<std::mutex> lock(mutex);
    if (!found) at = cell;
    found = true;
  }
};

/// Rows of cells scanned so far, for progress.
struct RowCount {
  std::atomic<std::int64_t> done{0};
  std::int64_t total = 0;
};

/// What the scan needs to know of one row of grid points along x (over a brick's cells): where its samples
/// change side of the isovalue, as in the first pass of flying edges. Cells left of every row's first change
/// and right of every row's last change are uncrossed when the rows agree at their ends.
struct PointRow {
  std::int64_t firstChange = 0;  ///< first cell index i (brick-local) with sign(i) != sign(i + 1), or end
  std::int64_t lastChange = -1;  ///< last such i, or -1
  bool firstPositive = false, lastPositive = false;
  bool nonFinite = false;  ///< a NaN or infinite sample: the row's cells take the careful path
};

PointRow summarizeRow(const double* v, std::int64_t begin, std::int64_t end, double iso) {
  PointRow row;
  row.firstChange = end;
  bool prev = v[begin] > iso;
  row.firstPositive = prev;
  bool finite = std::abs(v[begin]) <= std::numeric_limits<double>::max();
  for (std::int64_t i = begin + 1; i <= end; ++i) {
    const bool s = v[i] > iso;
    finite = finite && std::abs(v[i]) <= std::numeric_limits<double>::max();
    if (s != prev) {
      if (row.firstChange == end) row.firstChange = i - 1;
      row.lastChange = i - 1;
    }
    prev = s;
  }
  row.lastPositive = prev;
  row.nonFinite = !finite;
  return row;
}

/// A z-range of a brick's cell layers (brick-local, 0 = cellBegin[2]): the part of it one rank scans.
struct Layers {
  std::int64_t begin = 0, end = 0;
};

/// The summaries of the point rows of brick `b`'s cells: (ny + 1) * (nz + 1) rows, y fastest; only those of
/// the point layers `layers.begin` to `layers.end` (inclusive: the cells' corners) are filled.
std::vector<PointRow> summarizeRows(const GridBrick& b, double iso, Layers layers) {
  const std::int64_t ny = b.cellEnd[1] - b.cellBegin[1] + 1, nz = b.cellEnd[2] - b.cellBegin[2] + 1;
  std::vector<PointRow> rows(static_cast<std::size_t>(ny * nz));
  const std::int64_t first = ny * layers.begin, last = std::min(ny * nz, ny * (layers.end + 1));
  tbb::parallel_for(
      tbb::blocked_range<std::int64_t>(first, last, 64), [&](const tbb::blocked_range<std::int64_t>& r) {
        for (std::int64_t n = r.begin(); n != r.end(); ++n) {
          const double* v = &b.grid->values[static_cast<std::size_t>(
              b.grid->index(0, b.cellBegin[1] + n % ny, b.cellBegin[2] + n / ny))];
          rows[static_cast<std::size_t>(n)] = summarizeRow(v, b.cellBegin[0], b.cellEnd[0], iso);
        }
      });
  return rows;
}

/// The crossed cells of row (j, k) of brick `bi` (brick-local indices) and, with `listEdges`, their crossed
/// edges, sorted by key, each once. `rows` are the brick's point-row summaries.
void scanRow(const Input& in, std::uint32_t bi, std::int64_t j, std::int64_t k,
             const std::vector<PointRow>& rows, bool listEdges, std::vector<CellRef>& cells,
             std::vector<EdgeRef>& edges, NonFiniteCell& bad) {
  const GridBrick& b = in.bricks[bi];
  const DenseGrid& g = *b.grid;
  const double iso = in.options.isovalue;
  const std::int64_t rowsY = b.cellEnd[1] - b.cellBegin[1] + 1;
  const std::int64_t r0 = (j - b.cellBegin[1]) + rowsY * (k - b.cellBegin[2]);
  const PointRow* corner[4] = {&rows[static_cast<std::size_t>(r0)], &rows[static_cast<std::size_t>(r0 + 1)],
                               &rows[static_cast<std::size_t>(r0 + rowsY)],
                               &rows[static_cast<std::size_t>(r0 + rowsY + 1)]};
  std::int64_t lo = b.cellEnd[0], hi = b.cellBegin[0] - 1;
  bool careful = false, firstsAgree = true, lastsAgree = true;
  for (const PointRow* r : corner) {
    careful = careful || r->nonFinite;
    lo = std::min(lo, r->firstChange);
    hi = std::max(hi, r->lastChange);
    firstsAgree = firstsAgree && r->firstPositive == corner[0]->firstPositive;
    lastsAgree = lastsAgree && r->lastPositive == corner[0]->lastPositive;
  }
  if (careful || !firstsAgree) lo = b.cellBegin[0];
  if (careful || !lastsAgree) hi = b.cellEnd[0] - 1;
  if (lo > hi) return;
  const double* p[4] = {&g.values[static_cast<std::size_t>(g.index(0, j, k))],
                        &g.values[static_cast<std::size_t>(g.index(0, j + 1, k))],
                        &g.values[static_cast<std::size_t>(g.index(0, j, k + 1))],
                        &g.values[static_cast<std::size_t>(g.index(0, j + 1, k + 1))]};
  // Sign bits of the cell's x = 0 face (vertex x + 2y + 4z): rows (y, z) = (0,0), (1,0), (0,1), (1,1).
  auto side = [&](std::int64_t i) {
    return static_cast<unsigned>(p[0][i] > iso) | static_cast<unsigned>(p[1][i] > iso) << 2 |
           static_cast<unsigned>(p[2][i] > iso) << 4 | static_cast<unsigned>(p[3][i] > iso) << 6;
  };
  unsigned left = side(lo);
  for (std::int64_t i = lo; i <= hi; ++i) {
    const unsigned right = side(i + 1);
    const auto config = static_cast<std::uint8_t>(left | right << 1);
    left = right;
    if (careful) {
      bool finite = true;
      for (int r = 0; r < 4; ++r) finite = finite && std::isfinite(p[r][i]) && std::isfinite(p[r][i + 1]);
      if (!finite) {
        if (!in.options.skipNonFinite) bad.report({i + b.offset[0], j + b.offset[1], k + b.offset[2]});
        continue;
      }
    }
    if (config == 0 || config == 0xFF) continue;
    const std::array<std::int64_t, 3> cell{i + b.offset[0], j + b.offset[1], k + b.offset[2]};
    cells.push_back(CellRef{in.keys.point(cell[0], cell[1], cell[2]), bi, config});
    if (!listEdges) continue;
    std::uint16_t crossed = cube::crossedEdges(config);
    for (int e = 0; e < 12; ++e)
      if ((crossed >> e) & 1) edges.push_back(EdgeRef{in.keys.cellEdge(cell, e), bi});
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end(), sameKey), edges.end());
}

/// Appends the chunks' vectors to `out` in order, copying in parallel.
template <class T>
void appendRows(const std::vector<std::vector<T>>& rows, std::vector<T>& out) {
  std::vector<std::size_t> offset(rows.size() + 1, out.size());
  for (std::size_t r = 0; r < rows.size(); ++r) offset[r + 1] = offset[r] + rows[r].size();
  // Grow geometrically: the scan appends brick after brick (thousands of them in a sparse volume), and
  // reserving the exact size each time copied the whole table once per brick (a third of extracting smoke).
  if (offset.back() > out.capacity())
    reserveHuge(out, std::max(offset.back(), out.capacity() + out.capacity() / 2));
  resizeHuge(out, offset.back());
  tbb::parallel_for(std::size_t(0), rows.size(), [&](std::size_t r) {
    std::copy(rows[r].begin(), rows[r].end(), out.begin() + static_cast<std::ptrdiff_t>(offset[r]));
  });
}

/// The crossed edges of a brick whose samples are all finite, sorted by key, each once, found from the point
/// rows instead of the cells: with finite samples every grid edge of the brick whose ends lie on both sides
/// of the isovalue is an edge of one of its crossed cells, and the edges of a point row, in key order, are
/// those from its points in x order (axes 0, 1, 2 at each point). Rows go in parallel chunks.
std::vector<EdgeRef> brickEdges(const Input& in, std::uint32_t bi, const std::vector<PointRow>& rows,
                                Layers layers) {
  const GridBrick& b = in.bricks[bi];
  const DenseGrid& g = *b.grid;
  const double iso = in.options.isovalue;
  const std::int64_t ny = b.cellEnd[1] - b.cellBegin[1] + 1, nz = b.cellEnd[2] - b.cellBegin[2] + 1;
  const std::int64_t x0 = b.cellBegin[0], x1 = b.cellEnd[0];  // points x0 .. x1
  // The points where rows a and c may differ in sign (outside, each is uniform with the same side).
  auto between = [&](const PointRow& a, const PointRow& c, std::int64_t& lo, std::int64_t& hi) {
    lo = a.firstPositive != c.firstPositive ? x0 : std::min(a.firstChange, c.firstChange) + 1;
    hi = a.lastPositive != c.lastPositive ? x1 : std::max(a.lastChange, c.lastChange);
  };
  // The point rows of the layers' cells; the last layers also own the brick's last point layer.
  const std::int64_t first = ny * layers.begin, last = layers.begin == layers.end ? first
                                                       : layers.end + 1 == nz     ? ny * nz
                                                                                  : ny * layers.end;
  const std::int64_t chunks = (last - first + kRowChunk - 1) / kRowChunk;
  std::vector<std::vector<EdgeRef>> chunkEdges(static_cast<std::size_t>(chunks));
  tbb::parallel_for(std::int64_t(0), chunks, [&](std::int64_t chunk) {
    auto& out = chunkEdges[static_cast<std::size_t>(chunk)];
    const std::int64_t end = std::min(last, first + (chunk + 1) * kRowChunk);
    for (std::int64_t n = first + chunk * kRowChunk; n < end; ++n) {
      const std::int64_t jr = n % ny, kr = n / ny, j = b.cellBegin[1] + jr, k = b.cellBegin[2] + kr;
      const PointRow& a = rows[static_cast<std::size_t>(n)];
      const bool hasY = jr + 1 < ny, hasZ = kr + 1 < nz;
      std::int64_t lo = a.firstChange, hi = a.lastChange, ylo = 0, yhi = -1, zlo = 0, zhi = -1;
      if (hasY) between(a, rows[static_cast<std::size_t>(n + 1)], ylo, yhi);
      if (hasZ) between(a, rows[static_cast<std::size_t>(n + ny)], zlo, zhi);
      if (ylo <= yhi) lo = std::min(lo, ylo), hi = std::max(hi, yhi);
      if (zlo <= zhi) lo = std::min(lo, zlo), hi = std::max(hi, zhi);
      if (lo > hi) continue;
      const double* p = &g.values[static_cast<std::size_t>(g.index(0, j, k))];
      const double* py = hasY ? p + g.geometry.dims[0] : p;
      const double* pz = hasZ ? p + g.geometry.dims[0] * g.geometry.dims[1] : p;
      const Key row = in.keys.point(b.offset[0], j + b.offset[1], k + b.offset[2]) * 3;
      for (std::int64_t i = lo; i <= hi; ++i) {
        const bool s = p[i] > iso;
        const Key key = row + static_cast<Key>(i) * 3;
        if (i < x1 && s != (p[i + 1] > iso)) out.push_back(EdgeRef{key, bi});
        if (hasY && s != (py[i] > iso)) out.push_back(EdgeRef{key + 1, bi});
        if (hasZ && s != (pz[i] > iso)) out.push_back(EdgeRef{key + 2, bi});
      }
    }
  });
  std::vector<EdgeRef> edges;
  appendRows(chunkEdges, edges);
  return edges;
}

/// The cell layers `layers` of brick `bi`, their rows in parallel, appended to `scan` in row order. Rows go
/// in chunks of kRowChunk, each with its own output, so that few vectors grow (a vector per row made the scan
/// mostly page faults). With `ranks` (one brick split into z-slabs between them), the ranks agree whether
/// the whole brick is finite, so that all list its edges alike.
void scanBrick(const Input& in, std::uint32_t bi, Layers layers, const Collective* ranks, RowCount& rows,
               NonFiniteCell& bad, CellScan& scan) {
  const GridBrick& b = in.bricks[bi];
  std::int64_t ny = b.cellEnd[1] - b.cellBegin[1], nz = b.cellEnd[2] - b.cellBegin[2];
  if (ny <= 0 || nz <= 0 || b.cellEnd[0] <= b.cellBegin[0]) return;
  const std::vector<PointRow> pointRows = summarizeRows(b, in.options.isovalue, layers);
  // One brick with finite samples: its edges come from the point rows, already in key order (brickEdges).
  bool finite =
      std::none_of(pointRows.begin(), pointRows.end(), [](const PointRow& r) { return r.nonFinite; });
  if (ranks) finite = allRanks(*ranks, finite);
  const bool fromRows = in.bricks.size() == 1 && finite;
  const std::int64_t first = layers.begin * ny, last = layers.end * ny;
  const std::int64_t chunks = (last - first + kRowChunk - 1) / kRowChunk;
  std::vector<std::vector<CellRef>> chunkCells(static_cast<std::size_t>(chunks));
  std::vector<std::vector<EdgeRef>> chunkEdges(chunkCells.size());
  tbb::parallel_for(std::int64_t(0), chunks, [&](std::int64_t chunk) {
    thread_local std::vector<EdgeRef> rowEdges;
    auto& cells = chunkCells[static_cast<std::size_t>(chunk)];
    auto& edges = chunkEdges[static_cast<std::size_t>(chunk)];
    const std::int64_t begin = first + chunk * kRowChunk, end = std::min(last, begin + kRowChunk);
    for (std::int64_t row = begin; row < end; ++row) {
      rowEdges.clear();
      scanRow(in, bi, b.cellBegin[1] + row % ny, b.cellBegin[2] + row / ny, pointRows, !fromRows, cells,
              rowEdges, bad);
      edges.insert(edges.end(), rowEdges.begin(), rowEdges.end());
    }
    const std::int64_t done = rows.done += end - begin;
    in.progress.set(0.3 * static_cast<double>(done) / static_cast<double>(rows.total));
  });
  appendRows(chunkCells, scan.cells);
  if (fromRows) {
    scan.edges = brickEdges(in, bi, pointRows, layers);
    scan.edgesUnique = true;
  } else {
    appendRows(chunkEdges, scan.edges);
  }
}

/// The cell layers of brick `bi` this rank scans: all of them, or with `ranks`, one brick's rankShare of its
/// z-layers (slabs), or of several bricks those of its rankShare of the bricks (in brick order).
Layers scanLayers(const Input& in, std::uint32_t bi, const Collective* ranks) {
  const GridBrick& b = in.bricks[bi];
  const std::int64_t nz = std::max<std::int64_t>(0, b.cellEnd[2] - b.cellBegin[2]);
  if (!ranks) return {0, nz};
  if (in.bricks.size() == 1) {
    const auto [k0, k1] = rankShare(static_cast<std::size_t>(nz), ranks->rank(), ranks->size());
    return {static_cast<std::int64_t>(k0), static_cast<std::int64_t>(k1)};
  }
  const auto [b0, b1] = rankShare(in.bricks.size(), ranks->rank(), ranks->size());
  return bi >= b0 && bi < b1 ? Layers{0, nz} : Layers{0, 0};
}

/// Every rank's scan, joined in rank order: the scan one process makes (the ranks' layers and bricks are
/// consecutive runs in the order one process scans them).
CellScan joinScans(const Collective& ranks, const CellScan& mine) {
  static_assert(std::is_trivially_copyable_v<CellRef> && std::is_trivially_copyable_v<EdgeRef>);
  std::vector<std::uint8_t> bytes;
  const std::uint64_t counts[3] = {mine.cells.size(), mine.edges.size(), mine.edgesUnique ? 1u : 0u};
  appendBytes(bytes, counts, 3);
  appendBytes(bytes, mine.cells.data(), mine.cells.size());
  appendBytes(bytes, mine.edges.data(), mine.edges.size());
  const std::vector<std::vector<std::uint8_t>> all = ranks.allgather(bytes);
  CellScan scan;
  scan.edgesUnique = true;
  std::size_t cells = 0, edges = 0;
  std::vector<std::array<std::uint64_t, 3>> rankCounts(all.size());
  for (std::size_t r = 0; r < all.size(); ++r) {
    if (all[r].size() < sizeof rankCounts[r]) throw Error("scan: a rank sent no counts");
    std::memcpy(rankCounts[r].data(), all[r].data(), sizeof rankCounts[r]);
    if (all[r].size() !=
        sizeof rankCounts[r] + rankCounts[r][0] * sizeof(CellRef) + rankCounts[r][1] * sizeof(EdgeRef))
      throw Error("scan: rank " + std::to_string(r) + " sent a scan of another size");
    cells += rankCounts[r][0];
    edges += rankCounts[r][1];
    scan.edgesUnique = scan.edgesUnique && rankCounts[r][2];
  }
  resizeHuge(scan.cells, cells);
  resizeHuge(scan.edges, edges);
  cells = edges = 0;
  for (std::size_t r = 0; r < all.size(); ++r) {
    const std::uint8_t* p = all[r].data() + sizeof rankCounts[r];
    std::memcpy(scan.cells.data() + cells, p, rankCounts[r][0] * sizeof(CellRef));
    std::memcpy(scan.edges.data() + edges, p + rankCounts[r][0] * sizeof(CellRef),
                rankCounts[r][1] * sizeof(EdgeRef));
    cells += rankCounts[r][0];
    edges += rankCounts[r][1];
  }
  return scan;
}

// ---- Pass 3: isovertices ----

/// Central-difference gradient (index space) at a brick-local grid point; one-sided at the brick border.
Vec3 gridGradient(const DenseGrid& g, const std::array<std::int64_t, 3>& p) {
  Vec3 grad;
  for (int a = 0; a < 3; ++a) {
    auto lo = p, hi = p;
    if (p[a] > 0) lo[a] -= 1;
    if (p[a] + 1 < g.geometry.dims[a]) hi[a] += 1;
    double span = static_cast<double>(hi[a] - lo[a]);
    grad[a] = span > 0 ? (g.at(hi[0], hi[1], hi[2]) - g.at(lo[0], lo[1], lo[2])) / span : 0.0;
  }
  return grad;
}

/// The isovertex of one edge, from the samples of its brick (or the analytic field in exact mode).
IsoVertex edgeIsovertex(const Input& in, const SampledReference& reference, const EdgeRef& edge) {
  const BuildOptions& options = in.options;
  const double iso = options.isovalue;
  const GridBrick& b = in.bricks[edge.brick];
  const DenseGrid& g = *b.grid;
  const int axis = static_cast<int>(edge.key % 3);
  const auto gp = in.keys.coords(edge.key / 3);
  const std::array<std::int64_t, 3> lp = localPoint(b, gp);
  auto lq = lp;
  lq[axis] += 1;
  const double v0 = g.at(lp[0], lp[1], lp[2]), v1 = g.at(lq[0], lq[1], lq[2]);
  const Vec3 towardsPositive = Vec3::Unit(axis) * (v1 > iso ? 1.0 : -1.0);
  const Vec3 start(static_cast<double>(gp[0]), static_cast<double>(gp[1]), static_cast<double>(gp[2]));
  IsoVertex vx;
  double t;
  if (options.normals == NormalMode::Exact) {
    Vec3 wa = in.geometry.indexToWorld(start), wb = in.geometry.indexToWorld(start + Vec3::Unit(axis));
    t = exactCrossing(*options.exactField, wa, wb, iso);
    Vec3 gradWorld = options.exactField->gradient(wa + t * (wb - wa));
    vx.normal = orientCornerNormal(gradWorld.cwiseProduct(in.geometry.spacing), towardsPositive);
  } else {
    t = linearCrossing(v0, v1, iso);
    if (options.method == PatchMethod::Fitted && options.normals == NormalMode::Gradient) {
      const PointHermiteTable& table = reference.tables[edge.brick];
      t = cubicEdgeVertex(table.at(g.index(lp[0], lp[1], lp[2])), table.at(g.index(lq[0], lq[1], lq[2])),
                          axis, iso, vx.normal);
      // On a grid point, or next to a sample at the isovalue asked for (1/64 of a level off it,
      // Input::raise): see normalClearOfUncrossedEdges.
      const double asked = iso - in.raise;
      const bool on0 = v0 == iso || v0 == asked, on1 = v1 == iso || v1 == asked;
      if (on0 || on1)
        vx.normal = normalClearOfUncrossedEdges(g, on0 ? lp : lq, axis, iso, vx.normal, towardsPositive);
    } else if (options.normals == NormalMode::Edge) {
      vx.normal = towardsPositive;
    } else {
      vx.normal =
          orientCornerNormal((1 - t) * gridGradient(g, lp) + t * gridGradient(g, lq), towardsPositive);
    }
  }
  vx.position = start;
  vx.position[axis] += t;
  vx.weight = 1.0;
  return vx;
}

// ---- Pass 4: assembly ----

/// Each cell's first corner in Model::corners; returns the number of corners.
std::uint64_t layOutCorners(const std::vector<CellRef>& cells, std::vector<ModelCell>& modelCells) {
  std::uint64_t cornerTotal = 0;
  for (std::size_t c = 0; c < cells.size(); ++c) {
    modelCells[c].firstCorner = static_cast<std::uint32_t>(cornerTotal);
    cornerTotal += static_cast<std::uint64_t>(__builtin_popcount(cube::crossedEdges(cells[c].config)));
    if (cornerTotal > std::numeric_limits<std::uint32_t>::max())
      throw Error("too many corners for one model");
  }
  return cornerTotal;
}

/// Finds the isovertices of a run of cells in key order. The keys of a given edge of the cell (cell edge e)
/// increase with the cell's key, so each edge keeps a cursor into the sorted edge table that only moves
/// forward: a short gallop per lookup instead of a binary search over the whole table.
class EdgeCursors {
 public:
  explicit EdgeCursors(const std::vector<EdgeRef>& edges) : edges_(edges) { pos_.fill(0); }

  /// Index of `key` (present in the table) for cell edge `e`.
  std::size_t find(int e, Key key) {
    std::size_t& pos = pos_[static_cast<std::size_t>(e)];
    const std::size_t n = edges_.size();
    if (pos < n && edges_[pos].key == key) return pos;
    std::size_t step = 1, lo = pos, hi = pos;
    while (hi < n && edges_[hi].key < key) {  // gallop: lo < key <= hi
      lo = hi;
      hi = std::min(n, hi + step);
      step *= 2;
    }
    auto it = std::lower_bound(edges_.begin() + static_cast<std::ptrdiff_t>(lo),
                               edges_.begin() + static_cast<std::ptrdiff_t>(hi), key,
                               [](const EdgeRef& x, Key k) { return x.key < k; });
    pos = static_cast<std::size_t>(it - edges_.begin());
    if (pos >= n || edges_[pos].key != key) throw Error("crossed edge missing from the isovertex table");
    return pos;
  }

 private:
  const std::vector<EdgeRef>& edges_;
  std::array<std::size_t, 12> pos_;
};

/// The isovertices on the crossed edges of cell `gc` (its lowest point), in cell-local coordinates, and their
/// indices in the model's table.
void cellIsovertices(const Input& in, const CellRef& cell, const std::array<std::int64_t, 3>& gc,
                     EdgeCursors& cursors, const std::vector<IsoVertex>& vertices,
                     std::array<IsoVertex, 12>& local, std::array<std::uint32_t, 12>& vertexIndex) {
  const Vec3 origin(static_cast<double>(gc[0]), static_cast<double>(gc[1]), static_cast<double>(gc[2]));
  std::uint16_t crossed = cube::crossedEdges(cell.config);
  for (int e = 0; e < 12; ++e) {
    if (!((crossed >> e) & 1)) continue;
    vertexIndex[e] = static_cast<std::uint32_t>(cursors.find(e, in.keys.cellEdge(gc, e)));
    local[e] = vertices[vertexIndex[e]];
    local[e].position -= origin;
  }
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

/// The field minus the isovalue in cell-local coordinates of cell `gc`, for CentralRule::Interior: the
/// analytic field when there is one, else the trilinear interpolant of the cell's corner samples.
std::function<double(const Vec3&)> interiorReference(const Input& in, const CellRef& cell,
                                                     const std::array<std::int64_t, 3>& gc) {
  const double iso = in.options.isovalue;
  if (const ScalarField* field = in.options.exactField) {
    const Vec3 origin(static_cast<double>(gc[0]), static_cast<double>(gc[1]), static_cast<double>(gc[2]));
    return [field, &geometry = in.geometry, origin, iso](const Vec3& x) {
      return field->value(geometry.indexToWorld(origin + x)) - iso;
    };
  }
  const GridBrick& b = in.bricks[cell.brick];
  const std::array<std::int64_t, 3> lp = localPoint(b, gc);
  std::array<double, 8> v;
  for (int k = 0; k < 8; ++k) {
    auto vc = cube::vertexCoords(k);
    v[k] = b.grid->at(lp[0] + vc[0], lp[1] + vc[1], lp[2] + vc[2]);
  }
  return [v, iso](const Vec3& x) {
    double sum = 0;
    for (int k = 0; k < 8; ++k) {
      auto vc = cube::vertexCoords(k);
      sum += v[k] * (vc[0] ? x[0] : 1 - x[0]) * (vc[1] ? x[1] : 1 - x[1]) * (vc[2] ? x[2] : 1 - x[2]);
    }
    return sum - iso;
  };
}

/// One cell of the model: its loops, corners and (PatchMethod::Paper) coefficients into `mc` and its corner
/// slots of model.corners. Returns its loops.
CellLoops assembleCell(const Input& in, const CellRef& cell, EdgeCursors& edges, Model& model,
                       ModelCell& mc) {
  const auto gc = in.keys.coords(cell.key);
  std::array<IsoVertex, 12> local;
  std::array<std::uint32_t, 12> vertexIndex{};
  cellIsovertices(in, cell, gc, edges, model.vertices, local, vertexIndex);
  CellLoops loops;
  // PatchMethod::Fitted replaces the coefficients afterwards (fitModelPatches).
  const bool paperCoefficients = in.options.fitCoefficients && in.options.method == PatchMethod::Paper;
  CornerPatch patch = buildCellPatch(cell.config, local, &mc.pairing03, &loops, paperCoefficients);
  if (paperCoefficients && in.options.central == CentralRule::Interior) {
    Vec3 p;
    if (interiorPoint(patch, interiorReference(in, cell, gc), p))
      patch.central = fitCentralCoefficient(patch, p);
  }
  mc.index = {static_cast<std::uint32_t>(gc[0]), static_cast<std::uint32_t>(gc[1]),
              static_cast<std::uint32_t>(gc[2])};
  mc.config = cell.config;
  mc.numLoops = static_cast<std::uint8_t>(loops.numLoops);
  mc.loopSize = loops.loopSize;
  mc.faceCoefficient = patch.faceCoefficient;
  mc.central = patch.central;
  for (int k = 0; k < patch.numCorners; ++k) model.corners[mc.firstCorner + k] = vertexIndex[loops.edges[k]];
  return loops;
}

/// Each rank's share of the assembled cells (rankShare), their corners and, when kept, their loops, sent to
/// every rank: each ends with the whole table one process assembles.
void exchangeAssembled(const Collective& ranks, Model& model, std::vector<CellLoops>& loops) {
  static_assert(std::is_trivially_copyable_v<ModelCell> && std::is_trivially_copyable_v<CellLoops>);
  const std::size_t n = model.cells.size();
  auto cellRange = [&](int r) { return rankShare(n, r, ranks.size()); };
  exchangeRanges(
      ranks, sizeof(ModelCell), cellRange,
      [&](std::size_t c, std::vector<std::uint8_t>& out) { appendBytes(out, &model.cells[c], 1); },
      [&](std::size_t c, const std::uint8_t* p) { std::memcpy(&model.cells[c], p, sizeof(ModelCell)); });
  auto cornerRange = [&](int r) {
    const auto [c0, c1] = cellRange(r);
    auto at = [&](std::size_t c) {
      return c < n ? std::size_t{model.cells[c].firstCorner} : model.corners.size();
    };
    return std::make_pair(at(c0), at(c1));
  };
  exchangeRanges(
      ranks, sizeof(std::uint32_t), cornerRange,
      [&](std::size_t k, std::vector<std::uint8_t>& out) { appendBytes(out, &model.corners[k], 1); },
      [&](std::size_t k, const std::uint8_t* p) {
        std::memcpy(&model.corners[k], p, sizeof(std::uint32_t));
      });
  if (loops.empty()) return;
  exchangeRanges(
      ranks, sizeof(CellLoops), cellRange,
      [&](std::size_t c, std::vector<std::uint8_t>& out) { appendBytes(out, &loops[c], 1); },
      [&](std::size_t c, const std::uint8_t* p) { std::memcpy(&loops[c], p, sizeof(CellLoops)); });
}

}  // namespace

namespace {

/// Throws the NonFiniteSampleError of the first cell the scan found with a non-finite corner, if any.
void throwIfNonFinite(const NonFiniteCell& bad) {
  if (!bad.found) return;
  const auto& at = bad.at;
  throw NonFiniteSampleError("NaN or infinite voxel value in cell (" + std::to_string(at[0]) + "," +
                                 std::to_string(at[1]) + "," + std::to_string(at[2]) + ")",
                             {at[0], at[1], at[2]});
}

}  // namespace

Model emptyModel(const GridGeometry& geometry, const BuildOptions& options, const std::string& source) {
  Model model;
  model.geometry = geometry;
  model.isovalue = options.isovalue;
  model.normalMode = options.normals;
  model.method = options.method;
  model.source = source;
  return model;
}

CellScan scanCells(const Input& in) {
  CellScan scan;
  RowCount rows;
  // Split between ranks: each scans its slabs of a single brick or its share of the bricks, then the ranks
  // join their scans.
  const Collective* ranks = sharedBuild(in.options);
  std::vector<Layers> layers(in.bricks.size());
  for (std::uint32_t bi = 0; bi < in.bricks.size(); ++bi) {
    layers[bi] = scanLayers(in, bi, ranks);
    rows.total += std::max<std::int64_t>(0, in.bricks[bi].cellEnd[1] - in.bricks[bi].cellBegin[1]) *
                  (layers[bi].end - layers[bi].begin);
  }
  NonFiniteCell bad;
  for (std::uint32_t bi = 0; bi < in.bricks.size(); ++bi)
    if (layers[bi].begin < layers[bi].end || (ranks && in.bricks.size() == 1))  // a slab's rank agrees
      scanBrick(in, bi, layers[bi], ranks && in.bricks.size() == 1 ? ranks : nullptr, rows, bad, scan);
  throwIfNonFinite(bad);
  return ranks ? joinScans(*ranks, scan) : scan;
}

CellScan scanBrickCells(const Input& in, std::uint32_t brick) {
  CellScan scan;
  RowCount rows;
  const GridBrick& b = in.bricks[brick];
  rows.total = std::max<std::int64_t>(1, (b.cellEnd[1] - b.cellBegin[1]) * (b.cellEnd[2] - b.cellBegin[2]));
  NonFiniteCell bad;
  scanBrick(in, brick, scanLayers(in, brick, nullptr), nullptr, rows, bad, scan);
  throwIfNonFinite(bad);
  scan.edges = uniqueEdges(std::move(scan.edges), scan.edgesUnique);
  scan.edgesUnique = true;
  return scan;
}

void addToEstimate(const Input& in, const std::vector<CellRef>& cells, SamplingEstimator& estimator) {
  for (const CellRef& c : cells) {
    const GridBrick& b = in.bricks[c.brick];
    estimator.addCell(*b.grid, localPoint(b, in.keys.coords(c.key)));
  }
}

PointHermiteTable brickReference(const Input& in, const std::vector<CellRef>& cells, Reconstruction kind,
                                 const Collective* ranks) {
  if (cells.empty()) return {};
  const GridBrick& b = in.bricks[cells[0].brick];
  std::vector<std::int64_t> local(cells.size());
  tbb::parallel_for(std::size_t(0), cells.size(), [&](std::size_t n) {
    const auto lp = localPoint(b, in.keys.coords(cells[n].key));
    local[n] = b.grid->index(lp[0], lp[1], lp[2]);
  });
  return PointHermiteTable(*b.grid, local, kind, ranks);
}

SampledReference prepareReference(const Input& in, const std::vector<CellRef>& cells) {
  SampledReference reference;
  reference.sampled = in.options.method == PatchMethod::Fitted && in.options.normals != NormalMode::Exact;
  reference.kind = in.options.reconstruction;
  if (!reference.sampled) return reference;
  if (reference.kind == Reconstruction::Auto) {
    SamplingEstimator estimator;
    addToEstimate(in, cells, estimator);
    reference.sampling = estimator.estimate();
    reference.kind = chooseReconstruction(reference.sampling);
  }
  // The data at the corners of each brick's crossed cells, once per grid point.
  reference.tables.resize(in.bricks.size());
  if (in.bricks.size() == 1) {  // every cell in order; split between ranks by z-layers of the table's tiles
    reference.tables[0] = brickReference(in, cells, reference.kind, sharedBuild(in.options));
    return reference;
  }
  std::vector<std::vector<CellRef>> brickCells(in.bricks.size());
  for (const CellRef& c : cells) brickCells[c.brick].push_back(c);
  tbb::parallel_for(std::size_t(0), in.bricks.size(), [&](std::size_t bi) {
    reference.tables[bi] = brickReference(in, brickCells[bi], reference.kind);
  });
  return reference;
}

std::vector<EdgeRef> uniqueEdges(std::vector<EdgeRef> edges, bool alreadyUnique) {
  if (!alreadyUnique) {
    tbb::parallel_sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end(), sameKey), edges.end());
  }
  if (edges.size() > std::numeric_limits<std::uint32_t>::max())
    throw Error("too many isovertices for one model");
  return edges;
}

std::vector<IsoVertex> placeIsovertices(const Input& in, const SampledReference& reference,
                                        const std::vector<EdgeRef>& edges) {
  std::vector<IsoVertex> vertices;
  resizeHuge(vertices, edges.size());
  // Split between ranks: each places its share of the edges (in key order), then the ranks exchange them.
  const Collective* ranks = sharedBuild(in.options);
  auto share = [&](int r) { return rankShare(edges.size(), r, ranks ? ranks->size() : 1); };
  const auto [first, last] = share(ranks ? ranks->rank() : 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(first, last),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t n = r.begin(); n != r.end(); ++n)
                        vertices[n] = edgeIsovertex(in, reference, edges[n]);
                    });
  if (ranks)
    exchangeRanges(
        *ranks, 7 * sizeof(double), share,
        [&](std::size_t n, std::vector<std::uint8_t>& out) {
          const IsoVertex& v = vertices[n];
          const double d[7] = {v.position[0], v.position[1], v.position[2], v.normal[0],
                               v.normal[1],   v.normal[2],   v.weight};
          appendBytes(out, d, 7);
        },
        [&](std::size_t n, const std::uint8_t* p) {
          double d[7];
          std::memcpy(d, p, sizeof d);
          vertices[n].position = Vec3(d[0], d[1], d[2]);
          vertices[n].normal = Vec3(d[3], d[4], d[5]);
          vertices[n].weight = d[6];
        });
  return vertices;
}

std::vector<CellLoops> assembleCells(const Input& in, const std::vector<CellRef>& cells,
                                     const std::vector<EdgeRef>& edges, Model& model) {
  resizeHuge(model.cells, cells.size());
  const std::uint64_t corners = layOutCorners(cells, model.cells);
  resizeHuge(model.corners, corners);
  const bool keepLoops = fitsModelWide(in.options);   // the fitting works on them again
  const double end = keepLoops ? kFitProgress : 1.0;  // the fitting reports from there
  std::vector<CellLoops> loops(keepLoops ? cells.size() : 0);
  // Split between ranks: each assembles its share of the cells, then the ranks exchange them.
  const Collective* ranks = sharedBuild(in.options);
  // Not a structured binding: the lambda below uses both ends, and capturing a binding needs C++20 (clang
  // refuses it in C++17).
  const std::pair<std::size_t, std::size_t> share =
      ranks ? rankShare(cells.size(), ranks->rank(), ranks->size())
            : std::make_pair(std::size_t(0), cells.size());
  const std::size_t first = share.first, last = share.second;
  std::atomic<std::size_t> cellsDone{0};
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(first, last, 256), [&](const tbb::blocked_range<std::size_t>& r) {
        EdgeCursors cursors(edges);
        for (std::size_t c = r.begin(); c != r.end(); ++c) {
          CellLoops cellLoops = assembleCell(in, cells[c], cursors, model, model.cells[c]);
          if (keepLoops) loops[c] = cellLoops;
        }
        const std::size_t done = cellsDone += r.size();
        in.progress.set(0.5 + (end - 0.5) * static_cast<double>(done) / static_cast<double>(last - first));
      });
  if (ranks) exchangeAssembled(*ranks, model, loops);
  return loops;
}

void fitCoefficients(const Input& in, const std::vector<CellRef>& cells, const SampledReference& reference,
                     const std::vector<CellLoops>& loops, Model& model) {
  const BuildOptions& options = in.options;
  const double iso = options.isovalue;
  const Vec3 spacing = in.geometry.spacing;
  const Vec3 metric = Vec3::Constant(spacing.minCoeff()).cwiseQuotient(spacing);
  FittingStats stats = fitModelPatches(
      model, loops,
      [&](std::size_t c, CellReference& ref) {
        const auto& index = model.cells[c].index;  // as keys.coords(cells[c].key), without divisions
        const std::array<std::int64_t, 3> gc{index[0], index[1], index[2]};
        if (options.normals == NormalMode::Exact) {
          ref = CellReference();
          ref.field = options.exactField;
          ref.geometry = &model.geometry;
          ref.origin =
              Vec3(static_cast<double>(gc[0]), static_cast<double>(gc[1]), static_cast<double>(gc[2]));
          ref.isovalue = iso;
        } else {
          const GridBrick& b = in.bricks[cells[c].brick];
          reference.tables[cells[c].brick].setReference(localPoint(b, gc), iso, ref);
        }
        ref.metric = metric;
      },
      [&](double fraction) { in.progress.set(kFitProgress + (1 - kFitProgress) * fraction); },
      options.collective);
  if (reference.sampled) {
    model.reconstruction = reference.kind;
    stats.reconstruction = reference.kind;
    stats.sampling = reference.sampling;
  }
  if (options.fittingStats) *options.fittingStats = stats;
}

}  // namespace cip::build
