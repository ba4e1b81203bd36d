// The renderer against analytic surfaces: a sampled sphere (coverage; depth and normal errors as the patch
// surface sampled independently has them, and within the patch mesh test's distance bound; smaller at N = 32
// than at 16; no cracks even for rays along shared cell faces), a sampled plane as both constructions build
// it (reproduced exactly: depth at rounding level), thread-count determinism, EXR channels read back with
// OpenImageIO, meshes, the command's error path and its --stats-json. Every test writes into a folder of its
// own (support/scratch_dir.h).
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <vector>

#include "app.h"
#include "camera.h"
#include "cip/core/error.h"
#include "cip/measure/surface_fidelity.h"
#include "cip/mesh/ply.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/ray/ray_patch.h"
#include "cip/readers/volume_reader.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/analytic_field.h"
#include "image_output.h"
#include "mesh_scene.h"
#include "patch_scene.h"
#include "renderer.h"
#include "support/scratch_dir.h"
#include "support/volume_files.h"

using namespace cip;
using namespace cip::raycast;
namespace fs = std::filesystem;

namespace {

constexpr double kRadius = 0.75;  // analytic sphere: |x| - 0.75
constexpr double kPi = 3.14159265358979323846;

Model sampledModel(const std::string& field, int n) {
  auto f = makeAnalyticField(field);
  DenseGrid grid = sampleField(*f, n, field);
  BuildOptions options;
  options.normals = NormalMode::Exact;
  options.exactField = f.get();
  options.isovalue = f->defaultIsovalue();
  return buildModel(grid, options);
}

/// First intersection of a ray with the true sphere, or NaN.
double sphereHit(const Ray& r) {
  const double b = r.origin.dot(r.direction), c = r.origin.squaredNorm() - kRadius * kRadius;
  const double disc = b * b - c;
  return disc < 0 ? std::nan("") : -b - std::sqrt(disc);
}

/// Distance of the ray's line from the sphere's centre.
double missDistance(const Ray& r) {
  return (r.origin - r.origin.dot(r.direction) * r.direction).norm();
}

struct SphereErrors {
  int shouldHit = 0, missedInside = 0, hitOutside = 0;
  double maxDepth = 0, meanNormalDeg = 0, p99NormalDeg = 0, meanDepth = 0;
  double meanSignedDepth = 0;  ///< mean of (depth - true depth): negative where the surface lies outside
  double maxRadial = 0;        ///< largest | |hit| - R |: the hit's distance from the true sphere
  int judged = 0;              ///< pixels whose depth and normal were compared
  double judgedRadius = 0;     ///< the largest distance from the centre at which a ray's depth is judged
};

/// The largest depth error a ray can have when the surface it hits lies within `distance` of the true sphere
/// (radially) and the ray passes at most `miss` from the centre: the distance along the ray between the
/// spheres of radius R and R - distance (the larger of R + distance and R - distance; the ray meets the
/// sphere at incidence cos = sqrt(1 - (miss / R)^2)). Every pixel ray is compared with the same ray's exact
/// hit, so the pixel grid adds no error of its own.
double depthErrorBound(double distance, double miss) {
  const double inner = std::sqrt(std::max(0.0, (kRadius - distance) * (kRadius - distance) - miss * miss));
  const double outer = std::sqrt((kRadius + distance) * (kRadius + distance) - miss * miss);
  const double sphere = std::sqrt(kRadius * kRadius - miss * miss);
  return std::max(sphere - inner, outer - sphere);
}

/// Renders the sphere model and compares every pixel-centre ray with the true sphere. `margin`: pixels whose
/// ray passes within `margin` of the silhouette are not judged for coverage.
SphereErrors compareWithSphere(const PatchScene& scene, const Camera& camera, double margin) {
  RenderOptions options;
  options.threads = 2;
  RenderImage img = render(scene, camera, options);
  SphereErrors e;
  e.judgedRadius = kRadius - margin;
  std::vector<double> angles;
  double depthSum = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const std::size_t p = static_cast<std::size_t>(y) * img.width + x;
      const Ray ray = camera.ray(x + 0.5, y + 0.5);
      const double miss = missDistance(ray);
      const bool hit = img.id[p] != kNoHitId;
      if (miss < kRadius - margin) {
        ++e.shouldHit;
        if (!hit) ++e.missedInside;
      }
      if (miss > kRadius + margin && hit) ++e.hitOutside;
      if (!hit || miss > kRadius - margin) continue;
      const double truth = sphereHit(ray);
      const double err = std::abs(img.depth[p] - truth);
      e.maxDepth = std::max(e.maxDepth, err);
      depthSum += err;
      e.meanSignedDepth += img.depth[p] - truth;
      ++e.judged;
      const Vec3 n(img.normal[3 * p], img.normal[3 * p + 1], img.normal[3 * p + 2]);
      const Vec3 point = ray.origin + static_cast<double>(img.depth[p]) * ray.direction;
      e.maxRadial = std::max(e.maxRadial, std::abs(point.norm() - kRadius));
      angles.push_back(std::acos(std::clamp(n.dot(point.normalized()), -1.0, 1.0)) * 180 / kPi);
    }
  if (!angles.empty()) {
    double sum = 0;
    for (double a : angles) sum += a;
    e.meanNormalDeg = sum / static_cast<double>(angles.size());
    e.meanDepth = depthSum / static_cast<double>(angles.size());
    e.meanSignedDepth /= static_cast<double>(angles.size());
    std::sort(angles.begin(), angles.end());
    e.p99NormalDeg = angles[angles.size() * 99 / 100];
  }
  return e;
}

/// Orthographic view down -z with pixel size a quarter of the grid spacing (2/n). Every fourth column of
/// pixel-centre rays lies exactly in a grid plane x = const, so those rays run along faces shared by two
/// cells. With `onEdges` every fourth row lies in a plane y = const too, so some rays run exactly along cell
/// edges (through grid points).
Camera gridAlignedCamera(int n, bool onEdges) {
  const double pixel = 2.0 / (4.0 * n);
  const int size = 4 * n;
  const Vec3 look(0.5 * pixel, (onEdges ? -0.5 : -0.25) * pixel, 0);
  const double fov = 2 * std::atan(1.0 / 5.0) * 180 / kPi;
  return Camera(look + Vec3(0, 0, 5), look, Vec3::UnitY(), fov, true, size, size);
}

/// Independent reference for what the renderer must find: the first zero of the model's patches along the
/// ray, by visiting every cell (no BVH), sampling the patch densely over the ray's stretch in the cell and
/// bisecting the first sign change. Returns (t, cell) or nothing.
struct Oracle {
  const Model& model;
  std::vector<CornerPatch> patches;
  explicit Oracle(const Model& m) : model(m) {
    for (std::size_t c = 0; c < m.cells.size(); ++c) patches.push_back(m.patch(c));
  }
  Vec3 localOrigin(const Ray& r, std::size_t c) const {
    return model.geometry.worldToIndex(r.origin) - model.cellOrigin(c);
  }
  Vec3 localDirection(const Ray& r) const { return r.direction.cwiseQuotient(model.geometry.spacing); }

  std::optional<std::pair<double, std::uint32_t>> firstHit(const Ray& r, int samples = 300) const {
    std::optional<std::pair<double, std::uint32_t>> best;
    const Vec3 d = localDirection(r);
    for (std::size_t c = 0; c < patches.size(); ++c) {
      const Vec3 o = localOrigin(r, c);
      double t0, t1;
      if (!clipRayToCell(o, d, 0, std::numeric_limits<double>::infinity(), t0, t1)) continue;
      if (best && t0 > best->first) continue;
      auto f = [&](double t) { return patches[c].value(o + t * d); };
      // Sign changes between non-zero samples only: zeros without a sign change are not surface.
      double prevT = t0, prevV = f(t0);
      std::optional<double> root;
      for (int i = 1; i <= samples && !root; ++i) {
        const double t = t0 + (t1 - t0) * i / samples, v = f(t);
        if (v == 0) continue;
        if (prevV != 0 && (v < 0) != (prevV < 0)) {
          double lo = prevT, hi = t;
          for (int k = 0; k < 80; ++k) {
            const double m = 0.5 * (lo + hi), fm = f(m);
            if (fm == 0) {
              lo = hi = m;
              break;
            }
            ((fm < 0) == (prevV < 0) ? lo : hi) = m;
          }
          root = 0.5 * (lo + hi);
        }
        prevT = t;
        prevV = v;
      }
      if (root && (!best || *root < best->first)) best = std::make_pair(*root, static_cast<std::uint32_t>(c));
    }
    return best;
  }

  /// Whether t is a zero of cell c's patch along the ray: |value| tiny against the values a little way off.
  bool isZero(const Ray& r, double t, std::uint32_t c) const {
    const Vec3 o = localOrigin(r, c), d = localDirection(r);
    const double step = 1e-4 / d.norm();  // 1e-4 cell units
    const double v = std::abs(patches[c].value(o + t * d));
    const double around = std::max(std::abs(patches[c].value(o + (t - step) * d)),
                                   std::abs(patches[c].value(o + (t + step) * d)));
    return v <= 1e-6 * around;
  }
};

struct OracleComparison {
  int rays = 0, agree = 0, earlierZero = 0, cracks = 0, extra = 0, wrong = 0;
  double maxDiff = 0;
};

/// Casts every pixel-centre ray through the scene and the oracle.
OracleComparison compareWithOracle(const PatchScene& scene, const Oracle& oracle, const Camera& camera) {
  OracleComparison out;
  for (int y = 0; y < camera.height(); ++y)
    for (int x = 0; x < camera.width(); ++x) {
      const Ray ray = camera.ray(x + 0.5, y + 0.5);
      ++out.rays;
      SurfaceHit hit;
      const bool found = scene.intersect(ray, 0, std::numeric_limits<double>::infinity(), hit);
      const auto ref = oracle.firstHit(ray);
      if (ref && !found) {
        ++out.cracks;
        continue;
      }
      if (!found) continue;
      if (!oracle.isZero(ray, hit.t, hit.id)) {
        ++out.wrong;
        continue;
      }
      if (!ref) {
        ++out.extra;  // a touch or a root pair closer than the oracle's sampling
        continue;
      }
      const double diff = std::abs(hit.t - ref->first);
      if (diff <= 1e-9) {
        ++out.agree;
        out.maxDiff = std::max(out.maxDiff, diff);
      } else if (hit.t < ref->first) {
        ++out.earlierZero;  // a verified zero before the oracle's: a pair its sampling stepped over
      } else {
        ++out.wrong;  // the renderer skipped the first zero
      }
    }
  return out;
}

}  // namespace

// The renderer must return exactly the first zero of the patches along each ray (Embree traversal, cell
// clipping and the root finder together), including rays exactly along shared faces and cell edges.
TEST(Raycast, HitsAreTheFirstZerosOfThePatches) {
  for (const char* field : {"sphere", "torus", "plane"}) {
    const Model model = sampledModel(field, 16);
    const PatchScene scene(model);
    const Oracle oracle(model);
    for (int view : {0, 1, 2}) {
      const Camera camera =
          view == 0 ? makeCamera(CameraSettings{}, scene.bounds(), 48, 36) : gridAlignedCamera(8, view == 2);
      const OracleComparison c = compareWithOracle(scene, oracle, camera);
      const char* name = view == 0 ? "default view" : view == 1 ? "rays along faces" : "rays along edges";
      std::printf(
          "%s, %s: %d rays, %d agree (max diff %.2g), %d earlier zeros, %d extra, %d cracks, %d wrong\n",
          field, name, c.rays, c.agree, c.maxDiff, c.earlierZero, c.extra, c.cracks, c.wrong);
      EXPECT_EQ(c.cracks, 0) << field << ", " << name;
      EXPECT_EQ(c.wrong, 0) << field << ", " << name;
      EXPECT_GT(c.agree, c.rays / 10) << field << ", " << name;
      // Zeros without a sign change (at grid points and along uncrossed cell edges every patch term has a
      // vanishing squared bounding plane) are not surface: the renderer skips them, as the oracle does.
      EXPECT_LE(c.earlierZero + c.extra, c.rays / 100 + 2) << field << ", " << name;
    }
  }
}

/// What the rendered image of the sphere should show on average, computed independently of the renderer from
/// the patch surface sampled along axis-parallel lines (samplePatchSurface): the mean depth error and mean
/// normal error over the pixels whose rays pass within `judgedRadius` of the centre, for an orthographic view
/// along `view`. A line sample stands for the surface area s^2 / (|n_x| + |n_y| + |n_z|) (s: the lines'
/// spacing; the lines of the three axes meet the surface with density sum |n_a| / s^2), and a pixel for the
/// area whose projection it covers, so a sample weighs its area times cos(incidence); a ray's depth error is
/// the surface's radial distance over cos(incidence) (to first order in distance / R).
struct SphereExpectation {
  double meanDepth = 0, meanSignedDepth = 0, meanNormalDeg = 0;
};
SphereExpectation expectedFromLineSamples(const Model& model, const Vec3& view, double judgedRadius,
                                          int linesPerAxis) {
  const double h = model.geometry.spacing.x(), s = h / linesPerAxis;
  // Only the cells that can hold a point of the front half (half a cell diagonal from their centre).
  Model front = model;
  front.cells.clear();
  for (std::size_t c = 0; c < model.cells.size(); ++c)
    if (model.geometry.indexToWorld(model.cellOrigin(c) + Vec3::Constant(0.5)).dot(view) < h)
      front.cells.push_back(model.cells[c]);
  double depth = 0, signedDepth = 0, normal = 0, weight = 0;
  for (const SurfaceSample& sample : samplePatchSurface(front, linesPerAxis)) {
    const Vec3 radial = sample.world.normalized();
    const double cosine = -radial.dot(view);
    const Vec3 across = sample.world - sample.world.dot(view) * view;
    if (cosine <= 0 || across.norm() > judgedRadius) continue;  // not seen, or not judged
    const double area = s * s / radial.cwiseAbs().sum();
    depth += std::abs(sample.world.norm() - kRadius) * area;  // (distance / cos) * area * cos
    signedDepth -= (sample.world.norm() - kRadius) * area;    // outside the sphere: hit too early
    normal += std::acos(std::clamp(sample.normal.dot(radial), -1.0, 1.0)) * 180 / kPi * area * cosine;
    weight += area * cosine;
  }
  return {depth / weight, signedDepth / weight, normal / weight};
}

// The sampled sphere through the renderer against the true sphere: no pixel missed or hit wrongly, depth and
// normal errors as the patch surface itself has them, and smaller at N = 32 than at 16.
TEST(Raycast, SphereCoverageDepthNormalsShrinkWithResolution) {
  SphereErrors previous;
  const Vec3 view = Vec3(-0.3, -0.45, -1).normalized();  // no symmetry of the grid
  for (int n : {16, 32}) {
    const Model model = sampledModel("sphere", n);
    const PatchScene scene(model);
    const double h = 2.0 / n;  // grid spacing (world)
    // Orthographic, 1.6 world units across 160 pixels.
    const Camera camera(-5 * view, Vec3::Zero(), Vec3::UnitY(), 2 * std::atan(0.8 / 5) * 180 / kPi, true, 160,
                        160);
    const SphereErrors e = compareWithSphere(scene, camera, 0.5 * h);
    // 16 lines per cell and axis. Against the rendered means, the estimates with 8, 16 and 32 lines per cell
    // are: at N = 16, depth +5.8 %, -1.6 %, -0.3 %, normal +19 %, +0.7 %, +0.7 %; at N = 32, depth +0.3 %,
    // +0.3 %, -0.2 %, normal +3.2 %, +1.6 %, +1.1 %. With 16 lines the estimate is so within about 1.6 % of
    // the image's mean, and the tolerance below is twice that.
    const SphereExpectation expect = expectedFromLineSamples(model, view, e.judgedRadius, 16);
    std::printf(
        "N=%d: %d judged, missed inside %d, hit outside %d, depth max %.3g mean %.4g (expected %.4g), signed "
        "%.4g (expected %.4g) "
        "(voxels %.3g / %.3g), farthest hit %.3g voxels from the sphere, normal mean %.3f deg (expected "
        "%.3f) p99 %.2f deg\n",
        n, e.shouldHit, e.missedInside, e.hitOutside, e.maxDepth, e.meanDepth, expect.meanDepth,
        e.meanSignedDepth, expect.meanSignedDepth, e.maxDepth / h, e.meanDepth / h, e.maxRadial / h,
        e.meanNormalDeg, expect.meanNormalDeg, e.p99NormalDeg);
    EXPECT_GT(e.shouldHit, 10000);
    EXPECT_EQ(e.missedInside, 0) << "cracks";
    EXPECT_EQ(e.hitOutside, 0);
    // The renderer shows the patch surface's own errors: the image's means are those of the surface sampled
    // by lines (3 %: see above). A renderer that put its hits or normals a few percent off the patches
    // would fail here.
    EXPECT_NEAR(e.meanDepth, expect.meanDepth, 0.03 * expect.meanDepth);
    // Signed, where errors of both signs cancel: within the same 3 % of the mean error (a renderer biased by
    // that much along its rays, which the mean of absolute errors does not see, fails here).
    EXPECT_NEAR(e.meanSignedDepth, expect.meanSignedDepth, 0.03 * expect.meanDepth);
    EXPECT_NEAR(e.meanNormalDeg, expect.meanNormalDeg, 0.03 * expect.meanNormalDeg);
    // No hit farther from the sphere than PatchMesh.ExactSphereIsClosedAndOnTheSphere finds the vertices of
    // the same surface (0.25 voxel, at N = 16), and so no depth error beyond what that distance gives at the
    // most oblique ray judged.
    EXPECT_LT(e.maxRadial, 0.25 * h);
    EXPECT_LT(e.maxDepth, depthErrorBound(0.25 * h, e.judgedRadius));
    EXPECT_LT(e.p99NormalDeg, 480.0 / n);  // 30 and 15 degrees
    if (n == 32) {
      EXPECT_LT(e.maxDepth, 0.5 * previous.maxDepth);
      EXPECT_LT(e.meanDepth, 0.5 * previous.meanDepth);
      EXPECT_LT(e.meanNormalDeg, 0.75 * previous.meanNormalDeg);
    }
    previous = e;
  }
}

TEST(Raycast, NoCracksForRaysAlongSharedCellFaces) {
  for (int n : {16, 32}) {
    const Model model = sampledModel("sphere", n);
    const PatchScene scene(model);
    const double h = 2.0 / n;
    for (bool onEdges : {false, true}) {
      const SphereErrors e = compareWithSphere(scene, gridAlignedCamera(n, onEdges), 0.5 * h);
      EXPECT_GT(e.shouldHit, 100);
      EXPECT_EQ(e.missedInside, 0) << "N=" << n << (onEdges ? " along edges" : " along faces");
      EXPECT_EQ(e.hitOutside, 0) << "N=" << n << (onEdges ? " along edges" : " along faces");
      // As in SphereCoverageDepthNormalsShrinkWithResolution: hits within the patch mesh test's 0.25 voxel.
      EXPECT_LT(e.maxRadial, 0.25 * h) << "N=" << n << (onEdges ? " along edges" : " along faces");
      EXPECT_LT(e.maxDepth, depthErrorBound(0.25 * h, e.judgedRadius));
    }
  }
}

// A linear field, as built: every isovertex lies on the field's plane and every corner plane is that plane
// (exact normals, or central differences, which are exact for a linear field), so each patch is the plane
// times a positive sum of squares, plus side and central terms whose coefficients are zero in exact
// arithmetic (eq. 5 and the fit give 0 for a linear field; in doubles they come out as rounding noise, up to
// about 1e-11 for the paper's eq. 5). Both constructions must reproduce the plane: every ray that meets it
// inside the volume hits it at its analytic depth, with its normal.
TEST(Raycast, PlaneIsExact) {
  const Vec3 normal(0.3, -0.5, 0.81);  // 0.3 x - 0.5 y + 0.81 z - 0.05 = 0
  const double offset = 0.05;
  constexpr double kEps = std::numeric_limits<double>::epsilon();
  auto field = makeAnalyticField("plane");
  const DenseGrid grid = sampleField(*field, 16, "plane");
  for (PatchMethod method : {PatchMethod::Paper, PatchMethod::Fitted})
    for (NormalMode mode : {NormalMode::Exact, NormalMode::Gradient}) {
      BuildOptions options;
      options.method = method;
      options.normals = mode;
      options.exactField = field.get();
      options.isovalue = field->defaultIsovalue();
      const Model model = buildModel(grid, options);
      const PatchScene scene(model);
      const Camera camera = makeCamera(CameraSettings{}, scene.bounds(), 96, 72);
      const RenderImage img = render(scene, camera, RenderOptions{});
      int hits = 0;
      double maxErr = 0, maxUlps = 0, maxImageErr = 0, maxAngle = 0;
      for (int y = 0; y < camera.height(); ++y)
        for (int x = 0; x < camera.width(); ++x) {
          const Ray ray = camera.ray(x + 0.5, y + 0.5);
          const double truth = (offset - normal.dot(ray.origin)) / normal.dot(ray.direction);
          const Vec3 p = ray.origin + truth * ray.direction;
          const bool inside = (p.array().abs() < 1 - 1e-6).all();
          SurfaceHit hit;
          const bool found = scene.intersect(ray, 0, std::numeric_limits<double>::infinity(), hit);
          if (inside) {
            EXPECT_TRUE(found) << x << "," << y;
          }
          if (!found || !inside) continue;
          ++hits;
          maxErr = std::max(maxErr, std::abs(hit.t - truth));
          maxUlps = std::max(maxUlps, std::abs(hit.t - truth) / (kEps * truth));
          maxAngle = std::max(maxAngle, hit.normal.cross(normal.normalized()).norm());
          const std::size_t px = static_cast<std::size_t>(y) * camera.width() + x;
          maxImageErr = std::max(maxImageErr, std::abs(img.depth[px] - truth) / truth);
        }
      const std::string label = std::string(toString(method)) + ", " + toString(mode);
      std::printf(
          "plane, %s: %d hits, max depth error %.3g (%.1f eps t), max normal sin %.3g, image Z relative "
          "error %.3g\n",
          label.c_str(), hits, maxErr, maxUlps, maxAngle, maxImageErr);
      EXPECT_GT(hits, 1000) << label;
      // The root is refined to 2 eps t (ray_patch.cpp); the patch's value next to it is known to a few eps of
      // its terms, and the slope along the ray is the plane's (times the positive sum of squares), which is
      // small only near cell edges: 1.4 eps t (fitted) and 7.2 eps t (paper) at the worst pixel of this view.
      // Any error of the model's numbers beyond rounding (a side coefficient of 1e-9, an isovertex 1e-12 of a
      // cell off the plane) moves the hit by orders of magnitude more.
      EXPECT_LT(maxUlps, 32) << label;
      // The normal is the patch gradient: the plane's, tilted by the noise coefficients' terms (up to 1e-11
      // times their gradient, against the corner terms' gradient of order one): below 1e-12 at every pixel.
      EXPECT_LT(maxAngle, 1e-12) << label;
      // Z is stored as float: half a float ulp (2^-24 relative), plus the double error above.
      EXPECT_LT(maxImageErr, std::ldexp(1.0, -24) + 32 * kEps) << label;
    }
}

TEST(Raycast, ImageIsIdenticalForAnyThreadCount) {
  const Model model = sampledModel("torus", 24);
  const PatchScene scene(model);
  const Camera camera = makeCamera(CameraSettings{}, scene.bounds(), 64, 48);
  RenderOptions options;
  options.samplesPerPixel = 4;
  options.shading.shadows = true;
  for (ShadingMode mode : {ShadingMode::Phong, ShadingMode::Curvature}) {
    options.shading.mode = mode;
    options.threads = 1;
    RenderImage a = render(scene, camera, options);
    options.threads = 2;
    options.tileSize = 7;  // different tiling too
    RenderImage b = render(scene, camera, options);
    options.tileSize = 16;
    ASSERT_EQ(a.rgba.size(), b.rgba.size());
    EXPECT_EQ(0, std::memcmp(a.rgba.data(), b.rgba.data(), a.rgba.size() * sizeof(float)));
    EXPECT_EQ(0, std::memcmp(a.depth.data(), b.depth.data(), a.depth.size() * sizeof(float)));
    EXPECT_EQ(0, std::memcmp(a.normal.data(), b.normal.data(), a.normal.size() * sizeof(float)));
    EXPECT_EQ(a.id, b.id);
  }
}

TEST(Raycast, SamplePositionsAreStratified) {
  for (int spp : {1, 4, 5, 16}) {
    const int m = static_cast<int>(std::ceil(std::sqrt(spp)));
    const int rows = (spp + m - 1) / m;
    for (int s = 0; s < spp; ++s) {
      auto [u, v] = samplePosition(3, 7, s, spp);
      EXPECT_EQ(samplePosition(3, 7, s, spp), std::make_pair(u, v));  // a function of its arguments only
      if (spp == 1) {
        EXPECT_EQ(u, 0.5);
        EXPECT_EQ(v, 0.5);
        continue;
      }
      EXPECT_EQ(static_cast<int>(u * m), s % m);
      EXPECT_EQ(static_cast<int>(v * rows), s / m);
    }
  }
}

TEST(Raycast, ExrChannelsReadBack) {
  const Model model = sampledModel("sphere", 16);
  const PatchScene scene(model);
  const Camera camera = makeCamera(CameraSettings{}, scene.bounds(), 40, 30);
  RenderOptions options;
  const RenderImage img = render(scene, camera, options);
  const test::ScratchDir scratch;  // this test's own folder: the check below sees only its files
  const fs::path path = fs::path(scratch.path()) / "channels.exr";
  const fs::path png = fs::path(scratch.path()) / "channels.png";
  writeExr(img, path.string());
  writePng(img, png.string());
  std::vector<std::string> files;  // no temporaries left behind
  for (const auto& entry : fs::directory_iterator(scratch.path())) files.push_back(entry.path().filename());
  std::sort(files.begin(), files.end());
  EXPECT_EQ(files, (std::vector<std::string>{"channels.exr", "channels.png"}));

  auto in = OIIO::ImageInput::open(path.string());
  ASSERT_TRUE(in) << OIIO::geterror();
  const OIIO::ImageSpec& spec = in->spec();
  EXPECT_EQ(spec.width, 40);
  EXPECT_EQ(spec.height, 30);
  ASSERT_EQ(spec.nchannels, 9);
  auto channel = [&](const std::string& name) {
    for (int c = 0; c < spec.nchannels; ++c)
      if (spec.channelnames[c] == name) return c;
    return -1;
  };
  const int r = channel("R"), a = channel("A"), z = channel("Z"), nx = channel("N.x"), nz = channel("N.z"),
            id = channel("id");
  ASSERT_TRUE(r >= 0 && a >= 0 && z >= 0 && nx >= 0 && nz >= 0 && id >= 0);
  EXPECT_EQ(spec.channelformat(id), OIIO::TypeDesc::UINT32);
  EXPECT_EQ(spec.channelformat(z), OIIO::TypeDesc::FLOAT);
  std::vector<float> floats(img.pixels());
  std::vector<std::uint32_t> ids(img.pixels());
  auto readChannel = [&](int c, OIIO::TypeDesc type, void* out) {
    ASSERT_TRUE(in->read_image(0, 0, c, c + 1, type, out)) << in->geterror();
  };
  readChannel(id, OIIO::TypeDesc::UINT32, ids.data());
  EXPECT_EQ(ids, img.id);
  readChannel(z, OIIO::TypeDesc::FLOAT, floats.data());
  for (std::size_t p = 0; p < img.pixels(); ++p) {
    if (std::isinf(img.depth[p])) {
      EXPECT_TRUE(std::isinf(floats[p]));
    } else {
      EXPECT_EQ(floats[p], img.depth[p]);
    }
  }
  for (int c : {r, a, nx, nz}) {
    readChannel(c, OIIO::TypeDesc::FLOAT, floats.data());
    const int k = c == r ? 0 : c == a ? 3 : -1;
    for (std::size_t p = 0; p < img.pixels(); ++p) {
      const float expect = k >= 0 ? img.rgba[4 * p + k] : img.normal[3 * p + (c == nx ? 0 : 2)];
      EXPECT_EQ(floats[p], expect);
    }
  }
  in->close();

  auto pin = OIIO::ImageInput::open(png.string());
  ASSERT_TRUE(pin);
  EXPECT_EQ(pin->spec().nchannels, 3);
  EXPECT_EQ(pin->spec().format, OIIO::TypeDesc::UINT8);
}

TEST(Raycast, MeshSceneRendersTriangles) {
  // An octahedron |x| + |y| + |z| = 0.5 with outward counter-clockwise faces.
  TriangleMesh mesh;
  mesh.positions = {Vec3(0.5, 0, 0),  Vec3(-0.5, 0, 0), Vec3(0, 0.5, 0),
                    Vec3(0, -0.5, 0), Vec3(0, 0, 0.5),  Vec3(0, 0, -0.5)};
  for (int sx : {0, 1})
    for (int sy : {2, 3})
      for (int sz : {4, 5}) {
        std::array<std::uint32_t, 3> t{std::uint32_t(sx), std::uint32_t(sy), std::uint32_t(sz)};
        const Vec3 n =
            (mesh.positions[t[1]] - mesh.positions[t[0]]).cross(mesh.positions[t[2]] - mesh.positions[t[0]]);
        if (n.dot(mesh.positions[t[0]] + mesh.positions[t[1]] + mesh.positions[t[2]]) < 0)
          std::swap(t[1], t[2]);
        mesh.triangles.push_back(t);
      }
  const test::ScratchDir scratch;
  const fs::path ply = fs::path(scratch.path()) / "octahedron.ply";
  writePly(mesh, ply.string());
  const TriangleMesh read = readPly(ply.string());
  const MeshScene scene(read);
  EXPECT_EQ(scene.primitives(), 8u);
  const Camera camera = makeCamera(CameraSettings{}, scene.bounds(), 48, 48);
  const RenderImage img = render(scene, camera, RenderOptions{});
  int hits = 0;
  for (std::size_t p = 0; p < img.pixels(); ++p) {
    if (img.id[p] == kNoHitId) continue;
    ++hits;
    EXPECT_LT(img.id[p], 8u);
    const Vec3 n(img.normal[3 * p], img.normal[3 * p + 1], img.normal[3 * p + 2]);
    EXPECT_NEAR(n.cwiseAbs().sum(), std::sqrt(3.0), 1e-5);  // facet normals (+-1,+-1,+-1)/sqrt 3
    const Ray ray = camera.ray(static_cast<double>(p % 48) + 0.5, static_cast<double>(p / 48) + 0.5);
    EXPECT_LT(n.dot(ray.direction), 0);  // outward faces towards the camera
    const Vec3 x = ray.origin + static_cast<double>(img.depth[p]) * ray.direction;
    EXPECT_NEAR(x.cwiseAbs().sum(), 0.5, 1e-5);
  }
  EXPECT_GT(hits, 200);
}

TEST(Raycast, BadModelFileIsAnErrorAndWritesNothing) {
  const test::ScratchDir scratch;
  const fs::path dir = scratch.path();
  const fs::path bad = dir / "garbage.cip", out = dir / "never.exr", png = dir / "never.png";
  {
    std::ofstream f(bad, std::ios::binary);
    f << "this is not a model file";
  }
  AppOptions opt;
  opt.model = bad.string();
  opt.output = out.string();
  opt.png = png.string();
  opt.quiet = true;
  EXPECT_THROW(runApp(opt), cip::Error);
  opt.model = (dir / "does-not-exist.cip").string();
  EXPECT_THROW(runApp(opt), cip::Error);
  EXPECT_FALSE(fs::exists(out));
  EXPECT_FALSE(fs::exists(png));

  // A good model through the whole command: EXR, PNG and stats written.
  const fs::path good = dir / "sphere8.cip", stats = dir / "stats.json";
  writeModel(sampledModel("sphere", 8), good.string());
  opt.model = good.string();
  opt.size = "32x24";
  opt.statsJson = stats.string();
  EXPECT_EQ(runApp(opt), 0);
  EXPECT_TRUE(fs::exists(out));
  EXPECT_TRUE(fs::exists(png));
  EXPECT_TRUE(fs::exists(stats));
  opt.size = "32by24";
  EXPECT_THROW(runApp(opt), cip::Error);
  EXPECT_THROW(parseSize("0x10"), cip::Error);
}

// The memory estimate comes before the model is read: a limit below it is an error that writes nothing, and
// the stats say what the estimate was beside what the model and scene took.
TEST(Raycast, ModelsAboveTheMemoryLimitAreRefusedBeforeReading) {
  const test::ScratchDir scratch;
  const fs::path dir = scratch.path();
  const fs::path cip = dir / "sphere16.cip", out = dir / "m.exr", stats = dir / "m.json";
  const Model model = sampledModel("sphere", 16);
  writeModel(model, cip.string());
  AppOptions opt;
  opt.model = cip.string();
  opt.output = out.string();
  opt.size = "64x48";
  opt.quiet = true;
  opt.statsJson = stats.string();
  opt.memoryLimit = "64K";
  try {
    runApp(opt);
    FAIL() << "rendered above the memory limit";
  } catch (const cip::Error& e) {
    EXPECT_NE(std::string(e.what()).find("--memory-limit"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(out));
  EXPECT_FALSE(fs::exists(stats));
  opt.memoryLimit = "64 bytes";
  EXPECT_THROW(runApp(opt), cip::Error);
  opt.memoryLimit = "1G";
  ASSERT_EQ(runApp(opt), 0);
  std::ifstream in(stats);
  const nlohmann::json j = nlohmann::json::parse(in).at("memory");
  const std::uint64_t tables = model.cells.size() * sizeof(ModelCell) +
                               model.vertices.size() * sizeof(IsoVertex) +
                               model.corners.size() * sizeof(std::uint32_t);
  EXPECT_EQ(j.at("model_bytes").get<std::uint64_t>(), tables);
  EXPECT_EQ(j.at("limit_bytes").get<std::uint64_t>(), std::uint64_t{1} << 30);
  EXPECT_GE(j.at("estimated_peak_bytes").get<std::uint64_t>(), tables);
  // Embree reported the BVH it built (more than the zero masks alone).
  EXPECT_GT(j.at("scene_bytes").get<std::uint64_t>(), model.cells.size() * sizeof(std::uint64_t));
  EXPECT_GT(j.at("peak_rss_bytes").get<std::uint64_t>(), tables);
}

// The command itself: a bad model file gives one line on stderr, a non-zero exit status and no output files.
TEST(Raycast, CommandRejectsBadModelWithOneLine) {
  const test::ScratchDir scratch;
  const fs::path dir = scratch.path();
  const fs::path bad = dir / "garbage2.cip", out = dir / "cli.exr", png = dir / "cli.png",
                 err = dir / "cli.err";
  {
    std::ofstream f(bad, std::ios::binary);
    f << "CIPM but not really a model";
  }
  const std::string cmd = std::string(CIP_RAYCAST_EXE) + " '" + bad.string() + "' -o '" + out.string() +
                          "' --png '" + png.string() + "' 2> '" + err.string() + "'";
  const int status = std::system(cmd.c_str());
  EXPECT_NE(status, 0);
  EXPECT_FALSE(fs::exists(out));
  EXPECT_FALSE(fs::exists(png));
  std::ifstream in(err);
  std::string line, rest;
  std::getline(in, line);
  EXPECT_EQ(line.rfind("raycast: ", 0), 0u) << line;
  EXPECT_NE(line.find("garbage2.cip"), std::string::npos) << line;
  EXPECT_FALSE(std::getline(in, rest)) << "more than one line: " << rest;
  // --help documents every option with an example.
  const fs::path help = dir / "help.txt";
  ASSERT_EQ(std::system((std::string(CIP_RAYCAST_EXE) + " --help > '" + help.string() + "'").c_str()), 0);
  std::ifstream h(help);
  const std::string text((std::istreambuf_iterator<char>(h)), std::istreambuf_iterator<char>());
  for (const char* flag :
       {"--mesh", "--png", "--size", "--spp", "--eye", "--look", "--up", "--fov", "--ortho", "--shading",
        "--shadows", "--curvature-range", "--threads", "--stats-json", "--quiet"}) {
    auto at = text.find(std::string("  ") + flag);
    if (at == std::string::npos)
      at = text.find(std::string(",") + flag);  // short and long name, e.g. -q,--quiet
    ASSERT_NE(at, std::string::npos) << flag;
    const auto end = text.find("\n  -", at + 3);
    EXPECT_NE(text.substr(at, end - at).find("e.g."), std::string::npos) << flag;
  }
}

// The command's --stats-json, every figure against what the test knows on its own: the options given, the
// model, the camera those options define (up made orthogonal to the view), and the image read back from the
// EXR (a pixel's A is its share of samples that hit).
TEST(Raycast, StatsJsonReportsTheRun) {
  const test::ScratchDir scratch;
  const fs::path dir = scratch.path();
  const fs::path cip = dir / "torus.cip", exr = dir / "t.exr", json = dir / "stats.json";
  const Model model = sampledModel("torus", 12);
  writeModel(model, cip.string());
  const int width = 40, height = 30, spp = 4;
  const Vec3 eye(2.5, -3, 1.5), look(0.1, 0, -0.05), up(0, 0.2, 1);
  auto raycast = [&](const std::string& options) {
    const std::string cmd =
        std::string(CIP_RAYCAST_EXE) + " '" + cip.string() + "' -o '" + exr.string() +
        "' --size 40x30 --spp 4 --eye 2.5,-3,1.5 --look 0.1,0,-0.05 --up 0,0.2,1 --fov 30 " +
        "--threads 2 -q --stats-json '" + json.string() + "' " + options;
    EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
    std::ifstream in(json);
    return nlohmann::json::parse(in);
  };
  nlohmann::json j = raycast("--shading curvature --shadows");

  auto exrIn = OIIO::ImageInput::open(exr.string());
  ASSERT_TRUE(exrIn) << OIIO::geterror();
  int alpha = -1;
  for (int c = 0; c < exrIn->spec().nchannels; ++c)
    if (exrIn->spec().channelnames[c] == "A") alpha = c;
  ASSERT_GE(alpha, 0);
  std::vector<float> a(static_cast<std::size_t>(width) * height);
  ASSERT_TRUE(exrIn->read_image(0, 0, alpha, alpha + 1, OIIO::TypeDesc::FLOAT, a.data()));
  exrIn->close();
  std::int64_t hitPixels = 0, hitSamples = 0;
  for (float v : a) {
    hitPixels += v > 0;
    hitSamples += std::lround(v * spp);
  }
  ASSERT_GT(hitPixels, 0);
  ASSERT_LT(hitPixels, width * height);

  EXPECT_EQ(j.at("input"), cip.string());
  EXPECT_EQ(j.at("output"), exr.string());
  EXPECT_EQ(j.at("size"), nlohmann::json({width, height}));
  EXPECT_EQ(j.at("spp"), spp);
  EXPECT_EQ(j.at("threads"), 2);
  EXPECT_EQ(j.at("primitives"), model.cells.size());
  EXPECT_EQ(j.at("shading"), "curvature");
  EXPECT_EQ(j.at("shadows"), true);
  EXPECT_EQ(j.at("hit_pixels"), hitPixels);
  // spp rays per pixel and, with spp > 1, one more through its centre for the depth, normal and id channels.
  const std::int64_t primary = j.at("rays").at("primary"), shadow = j.at("rays").at("shadow");
  EXPECT_EQ(primary, std::int64_t{width} * height * (spp + 1));
  // One shadow ray per hit sample that faces the key light: some, and never more than the hit samples.
  EXPECT_GT(shadow, 0);
  EXPECT_LE(shadow, hitSamples);
  const double build = j.at("seconds").at("scene_build"), seconds = j.at("seconds").at("render");
  EXPECT_TRUE(std::isfinite(build) && build >= 0) << build;
  EXPECT_TRUE(std::isfinite(seconds) && seconds > 0) << seconds;
  EXPECT_NEAR(j.at("rays_per_second").get<double>(), static_cast<double>(primary + shadow) / seconds,
              1e-12 * static_cast<double>(primary + shadow) / seconds);
  const nlohmann::json& camera = j.at("camera");
  EXPECT_EQ(camera.at("eye"), nlohmann::json({eye.x(), eye.y(), eye.z()}));
  EXPECT_EQ(camera.at("look"), nlohmann::json({look.x(), look.y(), look.z()}));
  const Vec3 forward = (look - eye).normalized(), right = forward.cross(up).normalized();
  const Vec3 trueUp = right.cross(forward);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(camera.at("up").at(c).get<double>(), trueUp[c], 1e-15) << c;
  EXPECT_EQ(camera.at("fov"), 30.0);
  EXPECT_EQ(camera.at("orthographic"), false);
  // The automatic curvature range is symmetric about zero.
  ASSERT_EQ(j.at("curvature_range").size(), 2u);
  EXPECT_GT(j.at("curvature_range").at(1).get<double>(), 0);
  EXPECT_EQ(j.at("curvature_range").at(0).get<double>(), -j.at("curvature_range").at(1).get<double>());

  // Phong without shadows: no shadow rays and no curvature range.
  j = raycast("--shading phong");
  EXPECT_EQ(j.at("shading"), "phong");
  EXPECT_EQ(j.at("shadows"), false);
  EXPECT_EQ(j.at("rays").at("shadow"), 0);
  EXPECT_EQ(j.at("hit_pixels"), hitPixels);
  EXPECT_FALSE(j.contains("curvature_range"));
}

// Large renders restart the command once with glibc's huge-page heap (core/huge_pages.h): when it pays (a
// file of 64 KiB or more, or 2^20 samples or more), and that the restarted run writes the image of a run
// without it, byte for byte.
TEST(Raycast, LargeRendersRestartWithTheHugePageHeapAndGiveTheSameImage) {
  const test::ScratchDir scratch;
  const fs::path dir = scratch.path();
  const fs::path small = dir / "small.cip", large = dir / "large.cip";
  const Model model = sampledModel("torus", 20);
  writeModel(model, small.string());
  ModelFileOptions fullPrecision;
  fullPrecision.version = 1;
  writeModel(model, large.string(), fullPrecision);
  ASSERT_LT(fs::file_size(small), 64u << 10);
  ASSERT_GE(fs::file_size(large), 64u << 10);
  AppOptions o;
  o.model = small.string();
  o.size = "40x30";
  EXPECT_FALSE(wantsHugePageHeap(o));
  o.size = "1024x1024";
  EXPECT_TRUE(wantsHugePageHeap(o));
  o.size = "128x128";
  o.spp = 64;
  EXPECT_TRUE(wantsHugePageHeap(o));
  o.spp = 63;
  EXPECT_FALSE(wantsHugePageHeap(o));
  o.size = "not a size";
  EXPECT_FALSE(wantsHugePageHeap(o));
  o.model = large.string();
  EXPECT_TRUE(wantsHugePageHeap(o));
  o.model = (dir / "missing.cip").string();
  o.size = "40x30";
  EXPECT_FALSE(wantsHugePageHeap(o));
  o.model.clear();
  o.mesh = large.string();  // any input file counts by its size
  EXPECT_TRUE(wantsHugePageHeap(o));

  auto render = [&](const std::string& environment, const fs::path& exr) {
    const std::string cmd = environment + " " + CIP_RAYCAST_EXE + " '" + large.string() + "' -o '" +
                            exr.string() + "' --size 40x30 --threads 2 -q";
    EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
    std::ifstream in(exr, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  };
  const std::string restarted = render("", dir / "restarted.exr"),
                    plain = render("CIP_HUGE_PAGES=0", dir / "plain.exr");
  ASSERT_GT(plain.size(), 1000u);
  EXPECT_TRUE(restarted == plain);
}

TEST(Raycast, MeanCurvatureOfTheSphere) {
  // f = |x|: gradient x/r, Hessian (I - n n^T)/r: H = 1/r.
  const Vec3 p(0.3, -0.2, 0.6);
  const double r = p.norm();
  const Vec3 n = p / r;
  EXPECT_NEAR(cip::raycast::meanCurvature(n, (Mat3::Identity() - n * n.transpose()) / r), 1.0 / r, 1e-14);
  EXPECT_NEAR(cip::raycast::meanCurvature(-n, -(Mat3::Identity() - n * n.transpose()) / r), -1.0 / r, 1e-14);
  EXPECT_TRUE(std::isnan(cip::raycast::meanCurvature(Vec3::Zero(), Mat3::Identity())));
  // From the patches' exact Hessians, converted to world units: equal to half the divergence of the unit
  // world gradient by central differences. (The patch surface's own curvature does not converge to 1/r with
  // resolution: the median over the image is printed, and only checked for sign and size.)
  const Model model = sampledModel("sphere", 32);
  const PatchScene scene(model);
  const Camera camera = makeCamera(CameraSettings{}, scene.bounds(), 64, 48);
  std::vector<double> k;
  double maxRel = 0;
  for (int y = 0; y < camera.height(); ++y)
    for (int x = 0; x < camera.width(); ++x) {
      const Ray ray = camera.ray(x + 0.5, y + 0.5);
      SurfaceHit hit;
      if (!scene.intersect(ray, 0, std::numeric_limits<double>::infinity(), hit)) continue;
      ASSERT_TRUE(std::isfinite(hit.meanCurvature));
      k.push_back(hit.meanCurvature);
      const CornerPatch& patch = scene.patch(hit.id);
      auto unitGradient = [&](const Vec3& world) {
        const Vec3 g = patch.derivatives(scene.worldToLocal(world, hit.id))
                           .gradient.cwiseQuotient(model.geometry.spacing);
        return Vec3(g.normalized());
      };
      const double e = 1e-5 * model.geometry.spacing.x();
      double div = 0;
      for (int a = 0; a < 3; ++a) {
        const Vec3 d = e * Vec3::Unit(a);
        div += (unitGradient(hit.position + d)[a] - unitGradient(hit.position - d)[a]) / (2 * e);
      }
      maxRel = std::max(maxRel, std::abs(0.5 * div - hit.meanCurvature) / (1 + std::abs(hit.meanCurvature)));
    }
  ASSERT_GT(k.size(), 300u);
  EXPECT_LT(maxRel, 1e-4);
  std::nth_element(k.begin(), k.begin() + static_cast<std::ptrdiff_t>(k.size() / 2), k.end());
  std::printf(
      "sphere N=32: median mean curvature %.4f (true sphere %.4f), max deviation from differences %.2g\n",
      k[k.size() / 2], 1.0 / kRadius, maxRel);
  EXPECT_GT(k[k.size() / 2], 0.7 / kRadius);
  EXPECT_LT(k[k.size() / 2], 1.5 / kRadius);
  // Curvature mode: the automatic colour range is symmetric about zero.
  RenderOptions options;
  options.shading.mode = ShadingMode::Curvature;
  RenderStats stats;
  render(scene, camera, options, &stats);
  EXPECT_GT(stats.curvatureHi, 0);
  EXPECT_EQ(stats.curvatureLo, -stats.curvatureHi);
}

namespace {

/// A rotation by `degrees` about the unit `axis`.
Mat3 rotation(const Vec3& axis, double degrees) {
  return Eigen::AngleAxisd(degrees * kPi / 180, axis.normalized()).toRotationMatrix();
}

}  // namespace

// The patch surface of a rotated or flipped volume is the rotated (flipped) surface of the axis-aligned one:
// a model whose grid carries an orientation, seen by a camera moved with it, gives the same depths, and
// normals moved with it, as the axis-aligned model seen by the original camera.
TEST(PatchScene, OrientedGridRendersAsTheMovedAxisAlignedGrid) {
  const Model plain = sampledModel("torus", 20);
  Model moved = plain;
  const Mat3 flip = Vec3(1, -1, 1).asDiagonal();
  for (const Mat3& d : {rotation(Vec3(1, 2, 3), 37), Mat3(rotation(Vec3(-2, 1, 0.5), 110) * flip)}) {
    moved.geometry.direction = d;
    const PatchScene a(plain), b(moved);
    const Vec3 o = plain.geometry.origin;
    auto move = [&](const Vec3& p) { return Vec3(o + d * (p - o)); };
    // The moved scene's bounds lie within the box of the moved corners of the plain scene's box, and hold
    // every moved cell centre.
    Vec3 lo = Vec3::Constant(1e300), hi = -lo;
    for (int corner = 0; corner < 8; ++corner) {
      const Vec3 q = move(Vec3(corner & 1 ? a.bounds().hi.x() : a.bounds().lo.x(),
                               corner & 2 ? a.bounds().hi.y() : a.bounds().lo.y(),
                               corner & 4 ? a.bounds().hi.z() : a.bounds().lo.z()));
      lo = lo.cwiseMin(q);
      hi = hi.cwiseMax(q);
    }
    EXPECT_TRUE((b.bounds().lo.array() >= lo.array() - 1e-9).all());
    EXPECT_TRUE((b.bounds().hi.array() <= hi.array() + 1e-9).all());
    for (std::size_t c = 0; c < plain.cells.size(); ++c) {
      const Vec3 q = move(plain.geometry.indexToWorld(plain.cellOrigin(c) + Vec3::Constant(0.5)));
      ASSERT_TRUE((q.array() >= b.bounds().lo.array()).all() && (q.array() <= b.bounds().hi.array()).all());
    }
    const Camera ca = makeCamera(CameraSettings{}, a.bounds(), 48, 40);
    int hits = 0;
    double maxDepth = 0, maxNormal = 0;
    for (int y = 0; y < ca.height(); ++y)
      for (int x = 0; x < ca.width(); ++x) {
        const Ray r = ca.ray(x + 0.5, y + 0.5);
        const Ray rb{move(r.origin), d * r.direction};
        SurfaceHit ha, hb;
        const bool hitA = a.intersect(r, 0, std::numeric_limits<double>::infinity(), ha);
        const bool hitB = b.intersect(rb, 0, std::numeric_limits<double>::infinity(), hb);
        ASSERT_EQ(hitA, hitB) << "pixel " << x << "," << y;
        if (!hitA) continue;
        ++hits;
        maxDepth = std::max(maxDepth, std::abs(ha.t - hb.t));
        maxNormal = std::max(maxNormal, (d * ha.normal - hb.normal).norm());
        EXPECT_LT((move(ha.position) - hb.position).norm(), 1e-9);
        EXPECT_NEAR(ha.meanCurvature, hb.meanCurvature, 1e-6 * (1 + std::abs(ha.meanCurvature)));
      }
    EXPECT_GT(hits, 200);
    EXPECT_LT(maxDepth, 1e-9);
    EXPECT_LT(maxNormal, 1e-9);
  }
}

// With --space the scene converts the model's anatomical frame: RAS -> LPS negates x and y of every hit.
TEST(PatchScene, SpaceConversionNegatesXAndYFromRasToLps) {
  Model ras = sampledModel("sphere", 16);
  ras.geometry.space = WorldSpace::RAS;
  PatchSceneOptions lpsOptions;
  lpsOptions.space = WorldSpace::LPS;
  const PatchScene a(ras), b(ras, lpsOptions);
  const Vec3 s(-1, -1, 1);
  EXPECT_LT((b.bounds().lo - s.cwiseProduct(a.bounds().hi)).cwiseProduct(Vec3(1, 1, 0)).norm(), 1e-12);
  const Camera ca = makeCamera(CameraSettings{}, a.bounds(), 24, 20);
  int hits = 0;
  for (int y = 0; y < ca.height(); ++y)
    for (int x = 0; x < ca.width(); ++x) {
      const Ray r = ca.ray(x + 0.5, y + 0.5);
      SurfaceHit ha, hb;
      if (!a.intersect(r, 0, 1e9, ha)) continue;
      ASSERT_TRUE(b.intersect(Ray{s.cwiseProduct(r.origin), s.cwiseProduct(r.direction)}, 0, 1e9, hb));
      EXPECT_NEAR(ha.t, hb.t, 1e-12);
      EXPECT_LT((s.cwiseProduct(ha.normal) - hb.normal).norm(), 1e-12);
      ++hits;
    }
  EXPECT_GT(hits, 50);
  Model plain = sampledModel("sphere", 16);
  EXPECT_THROW(PatchScene(plain, lpsOptions), Error);  // no anatomical frame to convert from
}

namespace {

/// Sign of the region above the isovalue at an index-space point, from the model and the samples: the
/// patch's sign in non-empty cells, the corners' in empty ones (0 where a patch is exactly 0).
int regionSign(const Model& model, const DenseGrid& grid, double isovalue, const Vec3& x) {
  std::array<std::int64_t, 3> cell{};
  for (int a = 0; a < 3; ++a)
    cell[a] =
        std::clamp<std::int64_t>(static_cast<std::int64_t>(std::floor(x[a])), 0, grid.geometry.dims[a] - 2);
  const std::int64_t c = model.findCell(cell[0], cell[1], cell[2]);
  if (c < 0) return grid.at(cell[0], cell[1], cell[2]) > isovalue ? 1 : -1;
  const double v =
      model.patch(static_cast<std::size_t>(c)).value(x - model.cellOrigin(static_cast<std::size_t>(c)));
  return v > 0 ? 1 : v < 0 ? -1 : 0;
}

}  // namespace

// Where a patch takes the other sign than the corners on an open face (a face no neighbouring patch
// continues: docs/method.md, "Holes"), rays would pass through the surface. The renderer closes such holes
// with the piece of the face where the sign differs (open_face_cap.h): the surface it draws is the boundary
// of the region above the isovalue. Rays from many directions through a hole of each leaking cell of the
// bundled volume (which has a few) hit exactly where that region begins, as a walk along the ray finds it
// from the patches and the samples; some of those hits are on the face itself.
TEST(PatchScene, HolesOnOpenFacesAreClosed) {
  const SparseVolume volume = readVolume(test::sourceFile("data/blobs.nrrd"));
  const DenseGrid& grid = *volume.dense();
  BuildOptions o;
  o.isovalue = 128;
  const Model model = storedModel(buildModel(grid, o));
  const std::vector<std::uint32_t> leaking = openFaceLeakCells(model);
  ASSERT_GT(leaking.size(), 0u);  // else this test checks nothing; docs/method.md counts them
  const PatchScene scene(model, PatchSceneOptions{false, 1, WorldSpace::Unspecified});
  ASSERT_TRUE(model.geometry.spacing.isApprox(Vec3::Ones()) && model.geometry.origin.isZero());
  int rays = 0, onFaces = 0;
  for (std::uint32_t c : leaking) {
    const CornerPatch patch = model.patch(c);
    // The first point of the face lattice where the patch has the other sign than the face's corners.
    std::optional<std::pair<Vec3, int>> leak;
    for (int f = 0; f < 6 && !leak; ++f) {
      if ((patch.faceMask >> f) & 1) continue;
      const bool positive = (model.cells[c].config >> cube::faceVertex(f, 0)) & 1;
      const int axis = cube::faceAxis(f);
      for (int a = 0; a <= 32 && !leak; ++a)
        for (int b = 0; b <= 32 && !leak; ++b) {
          // The lattice of countOpenFaceLeaks, its border moved 1e-7 inside the face.
          Vec3 local;
          local[axis] = cube::faceSide(f);
          local[(axis + 1) % 3] = std::clamp(a / 32.0, 1e-7, 1 - 1e-7);
          local[(axis + 2) % 3] = std::clamp(b / 32.0, 1e-7, 1 - 1e-7);
          const double v = patch.value(local);
          if (v != 0 && (v > 0) != positive) leak = std::make_pair(model.cellOrigin(c) + local, f);
        }
    }
    ASSERT_TRUE(leak) << "cell " << c;
    const auto [point, face] = *leak;
    const int axis = cube::faceAxis(face);
    int cellOnFaces = 0;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          Vec3 d(dx, dy, dz);
          if (d[axis] == 0) continue;                        // along the face
          d = (d + Vec3(0.013, 0.021, 0.017)).normalized();  // off the grid's planes
          const Ray ray{point - 2.5 * d, d};
          SurfaceHit hit;
          const bool found = scene.intersect(ray, 0, 5, hit);
          // The walk: the first change of the region's sign, refined by bisection.
          std::optional<double> change;
          int previous = regionSign(model, grid, o.isovalue, ray.origin);
          for (double t = 5e-4; t <= 5 && !change; t += 5e-4) {
            const int s = regionSign(model, grid, o.isovalue, ray.origin + t * d);
            if (s != 0 && previous != 0 && s != previous) {
              double lo = t - 5e-4, hi = t;
              for (int k = 0; k < 60; ++k) {
                const double mid = 0.5 * (lo + hi);
                (regionSign(model, grid, o.isovalue, ray.origin + mid * d) == previous ? lo : hi) = mid;
              }
              change = 0.5 * (lo + hi);
            }
            if (s != 0) previous = s;
          }
          ++rays;
          ASSERT_EQ(found, change.has_value()) << "cell " << c << " direction " << d.transpose();
          if (!found) continue;
          EXPECT_NEAR(hit.t, *change, 1e-6) << "cell " << c << " direction " << d.transpose();
          if (std::abs(hit.t - 2.5) < 1e-9 && std::abs(std::abs(hit.normal[axis]) - 1) < 1e-12) ++cellOnFaces;
        }
    EXPECT_GT(cellOnFaces, 0) << "cell " << c;
    onFaces += cellOnFaces;
  }
  std::printf("%zu leaking cells, %d rays, %d hits on the faces that close the holes\n", leaking.size(), rays,
              onFaces);
  EXPECT_GT(rays, 0);
}
