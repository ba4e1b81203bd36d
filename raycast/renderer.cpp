#include "renderer.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>

#include "cip/core/error.h"
#include "cip/core/huge_pages.h"

namespace cip::raycast {

namespace {

std::uint64_t hash3(std::uint64_t a, std::uint64_t b, std::uint64_t c) {
  std::uint64_t x = a * 0x9e3779b97f4a7c15ull ^ (b + 0x632be59bd9b4e019ull) * 0xc2b2ae3d27d4eb4full ^
                    (c + 0x165667b19e3779f9ull) * 0xff51afd7ed558ccdull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

double unitFloat(std::uint64_t h) {
  return static_cast<double>(h >> 11) * (1.0 / 9007199254740992.0);
}

}  // namespace

std::pair<double, double> samplePosition(int x, int y, int s, int spp) {
  if (spp <= 1) return {0.5, 0.5};
  const int m = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(spp))));
  const int rows = (spp + m - 1) / m;
  const std::uint64_t h =
      hash3(static_cast<std::uint64_t>(x), static_cast<std::uint64_t>(y), static_cast<std::uint64_t>(s));
  const double jx = unitFloat(h), jy = unitFloat(hash3(h, 1, 2));
  return {(s % m + jx) / m, (s / m + jy) / rows};
}

namespace {

/// An image of the camera's size with every pixel a miss.
RenderImage blankImage(const Camera& camera) {
  RenderImage img;
  img.width = camera.width();
  img.height = camera.height();
  const std::size_t n = img.pixels();
  // Tens of megabytes at 1024x1024 and more: 2 MiB pages take 512 times fewer page faults to fill.
  auto fill = [n](auto& channel, std::size_t perPixel, auto value) {
    reserveHuge(channel, perPixel * n);
    channel.assign(perPixel * n, value);
  };
  fill(img.rgba, 4, 0.0f);
  fill(img.depth, 1, std::numeric_limits<float>::infinity());
  fill(img.normal, 3, 0.0f);
  fill(img.id, 1, kNoHitId);
  fill(img.curvature, 1, std::numeric_limits<float>::quiet_NaN());
  return img;
}

/// Renders tiles of the image: each pixel's samples and its centre ray. Tiles write disjoint pixels.
class TileRenderer {
 public:
  TileRenderer(const RenderScene& scene, const Camera& camera, const RenderOptions& options, RenderImage& img,
               std::vector<float>& light)
      : scene_(scene),
        camera_(camera),
        options_(options),
        frame_(makeShadingFrame(camera, scene.bounds())),
        img_(img),
        light_(light),
        tilesX_((img.width + tileSize() - 1) / tileSize()),
        tiles_(tilesX_ * ((img.height + tileSize() - 1) / tileSize())) {}

  int tiles() const { return tiles_; }

  /// Renders tile t (row-major over the tiles) and reports progress.
  void renderTile(int t) {
    const int tile = tileSize();
    const int x0 = (t % tilesX_) * tile, y0 = (t / tilesX_) * tile;
    const int x1 = std::min(img_.width, x0 + tile), y1 = std::min(img_.height, y0 + tile);
    std::int64_t rays = 0, shadowRays = 0;
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) renderPixel(x, y, rays, shadowRays);
    primary += rays;
    shadow += shadowRays;
    const std::int64_t d = ++done_;
    if (options_.progress) {
      std::lock_guard<std::mutex> lock(progressMutex_);
      options_.progress(static_cast<double>(d) / tiles_);
    }
  }

  std::atomic<std::int64_t> primary{0}, shadow{0};  ///< camera and shadow rays traced so far

 private:
  int tileSize() const { return std::max(1, options_.tileSize); }

  /// Colour, coverage, mean lighting and mean curvature over the pixel's samples; depth, normal and id from
  /// the ray through its centre.
  void renderPixel(int x, int y, std::int64_t& rays, std::int64_t& shadowRays) {
    const double inf = std::numeric_limits<double>::infinity();
    const int spp = options_.samplesPerPixel;
    const std::size_t p = static_cast<std::size_t>(y) * img_.width + x;
    Vec3 sum = Vec3::Zero();
    double curvatureSum = 0, lightSum = 0;
    int hits = 0, curvatureHits = 0;
    SurfaceHit hit;
    for (int s = 0; s < spp; ++s) {
      const auto [u, v] = samplePosition(x, y, s, spp);
      const Ray ray = camera_.ray(x + u, y + v);
      ++rays;
      if (!scene_.intersect(ray, 0.0, inf, hit)) continue;
      ++hits;
      const ShadedSample shaded = shade(hit, ray, scene_, frame_, options_.shading, shadowRays);
      sum += shaded.rgb;
      lightSum += shaded.light;
      if (std::isfinite(hit.meanCurvature)) {
        curvatureSum += hit.meanCurvature;
        ++curvatureHits;
      }
    }
    for (int c = 0; c < 3; ++c) img_.rgba[4 * p + c] = static_cast<float>(sum[c] / spp);
    img_.rgba[4 * p + 3] = static_cast<float>(static_cast<double>(hits) / spp);
    if (hits > 0) light_[p] = static_cast<float>(lightSum / hits);
    if (curvatureHits > 0) img_.curvature[p] = static_cast<float>(curvatureSum / curvatureHits);
    // Auxiliary channels from the ray through the pixel centre.
    bool centreHit;
    if (spp == 1) {
      centreHit = hits > 0;
    } else {
      ++rays;
      centreHit = scene_.intersect(camera_.ray(x + 0.5, y + 0.5), 0.0, inf, hit);
    }
    if (centreHit) {
      img_.depth[p] = static_cast<float>(hit.t);
      for (int c = 0; c < 3; ++c) img_.normal[3 * p + c] = static_cast<float>(hit.normal[c]);
      img_.id[p] = hit.id;
    }
  }

  const RenderScene& scene_;
  const Camera& camera_;
  const RenderOptions& options_;
  const ShadingFrame frame_;
  RenderImage& img_;
  std::vector<float>& light_;
  const int tilesX_, tiles_;
  std::atomic<std::int64_t> done_{0};
  std::mutex progressMutex_;
};

/// The curvature colour map's range: the given one, or symmetric about 0 with the 90th percentile of
/// |curvature| over the pixels that have one (1 if none or 0).
std::pair<double, double> curvatureRange(const RenderImage& img, const ShadingOptions& shading) {
  if (shading.curvatureRange) return *shading.curvatureRange;
  std::vector<float> mags;
  for (std::size_t p = 0; p < img.pixels(); ++p)
    if (std::isfinite(img.curvature[p])) mags.push_back(std::abs(img.curvature[p]));
  double k = 1;
  if (!mags.empty()) {
    const std::size_t at = std::min(mags.size() - 1, mags.size() * 9 / 10);
    std::nth_element(mags.begin(), mags.begin() + static_cast<std::ptrdiff_t>(at), mags.end());
    k = mags[at] > 0 ? mags[at] : 1.0;
  }
  return {-k, k};
}

/// Curvature mode: replaces each covered pixel's colour by the curvature colour, dimmed by its mean lighting.
void colourByCurvature(RenderImage& img, const std::vector<float>& light, double lo, double hi) {
  for (std::size_t p = 0; p < img.pixels(); ++p) {
    const float a = img.rgba[4 * p + 3];
    if (a <= 0) continue;
    const Vec3 c = curvatureColour(img.curvature[p], lo, hi) * (0.35 + 0.65 * light[p]) * a;
    for (int k = 0; k < 3; ++k) img.rgba[4 * p + k] = static_cast<float>(c[k]);
  }
}

}  // namespace

RenderImage render(const RenderScene& scene, const Camera& camera, const RenderOptions& options,
                   RenderStats* stats) {
  if (options.samplesPerPixel < 1) throw Error("samples per pixel must be at least 1");
  const auto start = std::chrono::steady_clock::now();
  RenderImage img = blankImage(camera);
  std::vector<float> light;  // curvature mode: mean lighting factor over hit samples
  reserveHuge(light, img.pixels());
  light.assign(img.pixels(), 0.0f);

  TileRenderer tiles(scene, camera, options, img, light);
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, tiles.tiles(), 1), [&](const tbb::blocked_range<int>& r) {
      for (int t = r.begin(); t != r.end(); ++t) tiles.renderTile(t);
    });
  });

  double lo = 0, hi = 0;
  if (options.shading.mode == ShadingMode::Curvature) {
    std::tie(lo, hi) = curvatureRange(img, options.shading);
    colourByCurvature(img, light, lo, hi);
  }

  if (stats) {
    stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    stats->threads = arena.max_concurrency();
    stats->primaryRays = tiles.primary;
    stats->shadowRays = tiles.shadow;
    stats->hitPixels = 0;
    for (std::size_t p = 0; p < img.pixels(); ++p) stats->hitPixels += img.rgba[4 * p + 3] > 0;
    stats->curvatureLo = lo;
    stats->curvatureHi = hi;
  }
  return img;
}

}  // namespace cip::raycast
