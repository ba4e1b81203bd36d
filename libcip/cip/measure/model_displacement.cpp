#include "cip/measure/model_displacement.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>

#include "cip/core/error.h"
#include "cip/ray/ray_patch.h"

namespace cip {

namespace {

constexpr double kRadToDeg = 57.29577951308232;
constexpr double kFootMargin = 0.5;   ///< Newton's landing point may leave the cell box by this much
constexpr double kConverged = 1e-10;  ///< |I| / |grad I| below this is on the zero set (voxels)
constexpr double kJitter = 0.8;       ///< fraction of a stratum the jitter spans (keeps lines off its edges)
constexpr double kRayStart = 2;       ///< rays start this far before the cell centre's plane
constexpr std::size_t kCellsPerTask = 16;

/// Count, sum, maximum and a histogram of non-negative values, merged in a fixed order (deterministic).
/// The 99th percentile is read from the histogram: the upper edge of the bin holding it (bins 2^(1/8)
/// apart, so within 9 %), at most the maximum.
class Tally {
 public:
  void add(double v) {
    ++count_;
    sum_ += v;
    max_ = std::max(max_, v);
    ++bins_[bin(v)];
  }
  void merge(const Tally& o) {
    count_ += o.count_;
    sum_ += o.sum_;
    max_ = std::max(max_, o.max_);
    for (int b = 0; b < kBins; ++b) bins_[b] += o.bins_[b];
  }
  ErrorSummary summary() const {
    ErrorSummary s;
    s.count = static_cast<std::size_t>(count_);
    if (count_ == 0) return s;
    s.mean = sum_ / static_cast<double>(count_);
    s.max = max_;
    const auto rank = static_cast<std::int64_t>(std::floor(0.99 * static_cast<double>(count_ - 1)));
    std::int64_t seen = 0;
    for (int b = 0; b < kBins; ++b) {
      seen += bins_[b];
      if (seen > rank) {
        s.p99 = std::min(max_, upperEdge(b));
        break;
      }
    }
    return s;
  }

 private:
  static constexpr int kPerOctave = 8;
  static constexpr int kMinExponent = -50, kMaxExponent = 14;
  static constexpr int kBins = (kMaxExponent - kMinExponent) * kPerOctave + 2;
  /// Bin 0: below 2^kMinExponent (0 included); the last: 2^kMaxExponent and beyond, and NaN.
  static int bin(double v) {
    if (!(v >= std::ldexp(1.0, kMinExponent))) return v < 1 ? 0 : kBins - 1;
    const double b = std::floor((std::log2(v) - kMinExponent) * kPerOctave) + 1;
    return b >= kBins - 1 ? kBins - 1 : static_cast<int>(b);
  }
  static double upperEdge(int b) {
    if (b >= kBins - 1) return std::numeric_limits<double>::infinity();
    return std::exp2(kMinExponent + static_cast<double>(b) / kPerOctave);
  }
  std::int64_t count_ = 0;
  double sum_ = 0, max_ = 0;
  std::array<std::int64_t, kBins> bins_{};
};

/// Everything gathered over a range of cells.
struct Totals {
  std::int64_t compared = 0, onlyInReference = 0, rays = 0, bothHit = 0, referenceOnly = 0, storedOnly = 0,
               firstOrder = 0;
  Tally depth, rayNormal, distance, normal, oneSided;
  double worstDistance = 0;   ///< cells that did not move are never the worst
  std::size_t worstCell = 0;  ///< reference cell index

  void merge(const Totals& o) {
    compared += o.compared;
    onlyInReference += o.onlyInReference;
    rays += o.rays;
    bothHit += o.bothHit;
    referenceOnly += o.referenceOnly;
    storedOnly += o.storedOnly;
    firstOrder += o.firstOrder;
    depth.merge(o.depth);
    rayNormal.merge(o.rayNormal);
    distance.merge(o.distance);
    normal.merge(o.normal);
    oneSided.merge(o.oneSided);
    if (o.worstDistance > worstDistance) {  // on a tie the earlier cell stays
      worstDistance = o.worstDistance;
      worstCell = o.worstCell;
    }
  }
};

/// A ray direction (unit, index space) and the bounding square of the unit cube's projection on the plane
/// across it, in the basis (e1, e2) of that plane, centred on the cube's centre.
struct Direction {
  Vec3 d, e1, e2;
  double lo1 = 0, hi1 = 0, lo2 = 0, hi2 = 0;
};

std::array<Direction, 7> rayDirections() {
  const std::array<Vec3, 7> dirs{Vec3(1, 0, 0),  Vec3(0, 1, 0),  Vec3(0, 0, 1), Vec3(1, 1, 1),
                                 Vec3(-1, 1, 1), Vec3(1, -1, 1), Vec3(1, 1, -1)};
  std::array<Direction, 7> out;
  for (std::size_t i = 0; i < dirs.size(); ++i) {
    Direction& r = out[i];
    r.d = dirs[i].normalized();
    if (i < 3) {  // the lines of the k x k face grid
      r.e1 = Vec3::Unit(static_cast<Eigen::Index>((i + 1) % 3));
      r.e2 = Vec3::Unit(static_cast<Eigen::Index>((i + 2) % 3));
    } else {
      r.e1 = r.d.cross(Vec3::UnitZ()).normalized();
      r.e2 = r.d.cross(r.e1);
    }
    r.lo1 = r.lo2 = std::numeric_limits<double>::infinity();
    r.hi1 = r.hi2 = -r.lo1;
    for (int v = 0; v < 8; ++v) {
      const Vec3 corner = Vec3(v & 1, (v >> 1) & 1, (v >> 2) & 1) - Vec3::Constant(0.5);
      r.lo1 = std::min(r.lo1, corner.dot(r.e1));
      r.hi1 = std::max(r.hi1, corner.dot(r.e1));
      r.lo2 = std::min(r.lo2, corner.dot(r.e2));
      r.hi2 = std::max(r.hi2, corner.dot(r.e2));
    }
  }
  return out;
}

std::uint64_t mix(std::uint64_t x) {  // splitmix64's finaliser
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

/// A deterministic number in [0, 1) per cell, direction, line and coordinate.
double jitter(const std::array<std::uint32_t, 3>& cell, std::size_t direction, int a, int b, int which) {
  std::uint64_t h = mix(cell[0]);
  h = mix(h ^ cell[1]);
  h = mix(h ^ cell[2]);
  h = mix(h ^ (direction << 40 | static_cast<std::uint64_t>(a) << 24 | static_cast<std::uint64_t>(b) << 8 |
               static_cast<std::uint64_t>(which)));
  return static_cast<double>(h >> 11) * 0x1.0p-53;
}

/// The angle between two gradients in degrees, or nothing when one vanishes. The atan2 form is exactly 0 for
/// equal directions and keeps its accuracy at small angles, where acos of the dot product does not.
std::optional<double> angleDegrees(const Vec3& a, const Vec3& b) {
  if (!(a.squaredNorm() > 0) || !(b.squaredNorm() > 0)) return std::nullopt;
  return kRadToDeg * std::atan2(a.cross(b).norm(), a.dot(b));
}

/// Where a hit's distance to the other zero set was measured: the distance (voxels), the other patch's
/// gradient there, and whether it is the first-order estimate.
struct Foot {
  double distance = 0;
  Vec3 gradient = Vec3::Zero();
  bool firstOrder = false;
};

/// Newton steps from p (cell-local) onto the zero set of q (see the header); the first-order estimate at p
/// when they do not converge inside the enlarged cell box.
Foot footOn(const CornerPatch& q, const Vec3& p, int steps) {
  const PatchDerivatives d0 = q.derivatives(p);
  if (d0.value == 0) return {0, d0.gradient, false};
  Vec3 x = p;
  PatchDerivatives d = d0;
  for (int it = 0; it < steps; ++it) {
    const double g2 = d.gradient.squaredNorm();
    if (!(g2 > 0)) break;
    const Vec3 step = d.value / g2 * d.gradient;
    x -= step;
    if ((x.array() < -kFootMargin).any() || (x.array() > 1 + kFootMargin).any()) break;
    d = q.derivatives(x);
    if (std::abs(d.value) <= kConverged * d.gradient.norm() || step.norm() < 1e-14)
      return {(x - p).norm(), d.gradient, false};
  }
  const double g0 = d0.gradient.norm();
  return {g0 > 0 ? std::abs(d0.value) / g0 : std::numeric_limits<double>::infinity(), d0.gradient, true};
}

/// The two patches of a cell and what the comparison needs about the grid.
struct CellPair {
  CornerPatch reference, stored;
  Vec3 spacing;
  int newtonSteps = 8;
};

/// A first hit on one patch along a ray: point (cell-local), ray parameter and world-space gradient.
struct Hit {
  Vec3 point;
  double t = 0;
  Vec3 gradient;
};

std::optional<Hit> firstHit(const CornerPatch& p, const Vec3& origin, const Vec3& d, const Vec3& spacing) {
  RootSearchOptions options;
  options.crossingsOnly = true;  // the surface separates the two signs, as the renderer sees it
  const auto root = intersectRayPatch(p, origin, d, 0, 2 * kRayStart, options);
  if (!root) return std::nullopt;
  const Vec3 x = origin + root->t * d;
  return Hit{x, root->t, p.derivatives(x).gradient.cwiseQuotient(spacing)};
}

/// One hit's distance to the other patch's zero set and normal against the other patch's normal there;
/// `other` is the other patch's hit on the same ray, if any. Returns the distance.
double sideSample(const Hit& hit, const CornerPatch& otherPatch, const std::optional<Hit>& other,
                  const CellPair& pair, Totals& t) {
  Foot foot;
  const double along = other ? std::abs(hit.t - other->t) : std::numeric_limits<double>::infinity();
  if (along > 0) foot = footOn(otherPatch, hit.point, pair.newtonSteps);
  if (other && along <= foot.distance) {
    foot = Foot{along, other->gradient, false};
  } else {
    foot.gradient = foot.gradient.cwiseQuotient(pair.spacing);
  }
  t.distance.add(foot.distance);
  if (!other) t.oneSided.add(foot.distance);
  if (foot.firstOrder) ++t.firstOrder;
  if (const auto angle = angleDegrees(hit.gradient, foot.gradient)) t.normal.add(*angle);
  return foot.distance;
}

/// Casts one ray through both patches; returns the largest distance it found (0 without hits).
double compareRay(const CellPair& pair, const Vec3& origin, const Vec3& d, Totals& t) {
  const auto a = firstHit(pair.reference, origin, d, pair.spacing);
  const auto b = firstHit(pair.stored, origin, d, pair.spacing);
  if (a && b) {
    ++t.bothHit;
    t.depth.add(std::abs(a->t - b->t));
    if (const auto angle = angleDegrees(a->gradient, b->gradient)) t.rayNormal.add(*angle);
  } else if (a) {
    ++t.referenceOnly;
  } else if (b) {
    ++t.storedOnly;
  }
  double worst = 0;
  if (a) worst = std::max(worst, sideSample(*a, pair.stored, b, pair, t));
  if (b) worst = std::max(worst, sideSample(*b, pair.reference, a, pair, t));
  return worst;
}

/// All rays through one cell; returns the largest distance found.
double compareCell(const CellPair& pair, const std::array<std::uint32_t, 3>& cell,
                   const std::array<Direction, 7>& directions, int k, Totals& t) {
  double worst = 0;
  const Vec3 centre = Vec3::Constant(0.5);
  for (std::size_t di = 0; di < directions.size(); ++di) {
    const Direction& r = directions[di];
    for (int a = 0; a < k; ++a)
      for (int b = 0; b < k; ++b) {
        const double u = (a + 0.5 + kJitter * (jitter(cell, di, a, b, 0) - 0.5)) / k;
        const double v = (b + 0.5 + kJitter * (jitter(cell, di, a, b, 1) - 0.5)) / k;
        const Vec3 origin = centre + (r.lo1 + u * (r.hi1 - r.lo1)) * r.e1 +
                            (r.lo2 + v * (r.hi2 - r.lo2)) * r.e2 - kRayStart * r.d;
        double t0 = 0, t1 = 0;
        if (!clipRayToCell(origin, r.d, 0, 2 * kRayStart, t0, t1)) continue;  // the line misses the cell
        ++t.rays;
        worst = std::max(worst, compareRay(pair, origin, r.d, t));
      }
  }
  return worst;
}

ModelDisplacement toResult(const Totals& t) {
  ModelDisplacement out;
  out.cellsCompared = t.compared;
  out.cellsOnlyInReference = t.onlyInReference;
  out.rays = t.rays;
  out.bothHit = t.bothHit;
  out.referenceOnlyHits = t.referenceOnly;
  out.storedOnlyHits = t.storedOnly;
  out.firstOrderEstimates = t.firstOrder;
  out.depthVoxels = t.depth.summary();
  out.rayNormalDegrees = t.rayNormal.summary();
  out.distanceVoxels = t.distance.summary();
  out.normalDegrees = t.normal.summary();
  out.oneSidedDistanceVoxels = t.oneSided.summary();
  return out;
}

}  // namespace

ModelDisplacement measureModelDisplacement(const Model& reference, const Model& stored,
                                           const DisplacementOptions& options) {
  if (reference.geometry.dims != stored.geometry.dims)
    throw Error("the models to compare have different grids");
  if (options.raysPerAxis < 1) throw Error("raysPerAxis must be at least 1");
  const std::array<Direction, 7> directions = rayDirections();
  const Vec3 spacing = reference.geometry.spacing;
  std::vector<double> cellDistance(options.perCell ? reference.cells.size() : 0);
  const Totals totals = tbb::parallel_deterministic_reduce(
      tbb::blocked_range<std::size_t>(0, reference.cells.size(), kCellsPerTask), Totals(),
      [&](const tbb::blocked_range<std::size_t>& range, Totals t) {
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
          const auto& index = reference.cells[c].index;
          const std::int64_t s = stored.findCell(index[0], index[1], index[2]);
          double worst = std::numeric_limits<double>::quiet_NaN();
          if (s < 0) {
            ++t.onlyInReference;
          } else {
            ++t.compared;
            const CellPair pair{reference.patch(c), stored.patch(static_cast<std::size_t>(s)), spacing,
                                options.newtonSteps};
            worst = compareCell(pair, index, directions, options.raysPerAxis, t);
            if (worst > t.worstDistance) {
              t.worstDistance = worst;
              t.worstCell = c;
            }
          }
          if (options.perCell) cellDistance[c] = worst;
        }
        return t;
      },
      [](Totals a, const Totals& b) {
        a.merge(b);
        return a;
      });
  ModelDisplacement out = toResult(totals);
  out.sameGeometry =
      reference.geometry.origin == stored.geometry.origin && spacing == stored.geometry.spacing;
  for (const ModelCell& cell : stored.cells)
    if (reference.findCell(cell.index[0], cell.index[1], cell.index[2]) < 0) ++out.cellsOnlyInStored;
  if (totals.worstDistance > 0) out.worstCell = reference.cells[totals.worstCell].index;
  out.cellDistance = std::move(cellDistance);
  return out;
}

}  // namespace cip
