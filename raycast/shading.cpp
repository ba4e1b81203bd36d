#include "shading.h"

#include <algorithm>
#include <cmath>

#include "cip/core/error.h"

namespace cip::raycast {

namespace {

double byteAt(std::uint64_t h, int shift) {
  return static_cast<double>((h >> shift) & 0xff) / 255.0;
}

std::uint64_t mix(std::uint64_t x) {  // splitmix64 finaliser
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

const Vec3 kBase(0.78, 0.74, 0.68);      // front side (the side the gradient points to)
const Vec3 kBackBase(0.50, 0.58, 0.78);  // back side: makes holes and inverted sheets visible

}  // namespace

ShadingMode parseShadingMode(const std::string& name) {
  if (name == "phong") return ShadingMode::Phong;
  if (name == "cells") return ShadingMode::Cells;
  if (name == "normal") return ShadingMode::Normal;
  if (name == "depth") return ShadingMode::Depth;
  if (name == "curvature") return ShadingMode::Curvature;
  if (name == "isophotes") return ShadingMode::Isophotes;
  throw Error("unknown shading mode '" + name +
              "' (expected phong, cells, normal, depth, curvature or isophotes)");
}

const char* toString(ShadingMode mode) {
  switch (mode) {
    case ShadingMode::Phong:
      return "phong";
    case ShadingMode::Cells:
      return "cells";
    case ShadingMode::Normal:
      return "normal";
    case ShadingMode::Depth:
      return "depth";
    case ShadingMode::Curvature:
      return "curvature";
    case ShadingMode::Isophotes:
      return "isophotes";
  }
  return "?";
}

ShadingFrame makeShadingFrame(const Camera& camera, const Box& bounds) {
  ShadingFrame f;
  const Vec3 back = -camera.forward();
  f.keyLight = (-0.45 * camera.right() + 0.75 * camera.up() + 0.9 * back).normalized();
  f.fillLight = (0.85 * camera.right() - 0.15 * camera.up() + 0.5 * back).normalized();
  f.eye = camera.eye();
  f.forward = camera.forward();
  const double radius = std::max(bounds.radius(), 1e-12);
  const double centre = (bounds.center() - camera.eye()).dot(camera.forward());
  f.depthNear = std::max(0.0, centre - radius);
  f.depthFar = centre + radius;
  f.rayOffset = 1e-6 * (radius + (bounds.center() - camera.eye()).norm());
  return f;
}

Vec3 curvatureColour(double k, double lo, double hi) {
  const Vec3 blue(0.16, 0.32, 0.85), white(0.95, 0.95, 0.95), red(0.85, 0.18, 0.12);
  if (!std::isfinite(k)) return Vec3(0.3, 0.3, 0.3);
  const double mid = 0.5 * (lo + hi), half = 0.5 * (hi - lo);
  const double s = half > 0 ? std::clamp((k - mid) / half, -1.0, 1.0) : 0.0;
  return s < 0 ? Vec3(white + (-s) * (blue - white)) : Vec3(white + s * (red - white));
}

Vec3 cellColour(const SurfaceHit& hit) {
  if (!hit.hasCellIndex) {
    const std::uint64_t h = mix(hit.id);
    return Vec3(0.35 + 0.6 * byteAt(h, 0), 0.35 + 0.6 * byteAt(h, 8), 0.35 + 0.6 * byteAt(h, 16));
  }
  const auto& c = hit.cellIndex;
  const std::uint64_t h = mix((std::uint64_t(c[0]) * 73856093u) ^ (std::uint64_t(c[1]) * 19349663u) ^
                              (std::uint64_t(c[2]) * 83492791u));
  const double v = 0.75 + 0.25 * byteAt(h, 0);
  const double tint = byteAt(h, 16);
  if ((c[0] + c[1] + c[2]) & 1) return v * Vec3(0.95, 0.55 + 0.25 * tint, 0.25);  // warm palette
  return v * Vec3(0.25, 0.55 + 0.25 * tint, 0.95);                                // cool palette
}

ShadedSample shade(const SurfaceHit& hit, const Ray& ray, const RenderScene& scene, const ShadingFrame& frame,
                   const ShadingOptions& options, std::int64_t& shadowRays) {
  ShadedSample out;
  const bool front = hit.normal.dot(ray.direction) <= 0;
  const Vec3 n = front ? hit.normal : Vec3(-hit.normal);  // towards the viewer
  const double keyDot = std::max(0.0, n.dot(frame.keyLight));
  double key = keyDot;
  if (options.shadows && keyDot > 0) {
    Ray shadow;
    shadow.origin = hit.position + frame.rayOffset * n;
    shadow.direction = frame.keyLight;
    ++shadowRays;
    if (scene.occluded(shadow, frame.rayOffset, std::numeric_limits<double>::infinity())) key = 0;
  }
  const double fill = std::max(0.0, n.dot(frame.fillLight));
  const double diffuse = std::min(1.0, 0.1 + 0.75 * key + 0.25 * fill);
  out.light = diffuse;
  switch (options.mode) {
    case ShadingMode::Phong: {
      const Vec3 h = (frame.keyLight - ray.direction).normalized();
      const double spec = key > 0 ? 0.3 * std::pow(std::max(0.0, n.dot(h)), 48.0) : 0.0;
      out.rgb = diffuse * (front ? kBase : kBackBase) + Vec3::Constant(spec);
      break;
    }
    case ShadingMode::Cells:
      out.rgb = (0.25 + 0.75 * diffuse) * cellColour(hit);
      break;
    case ShadingMode::Normal:
      out.rgb = 0.5 * (hit.normal + Vec3::Ones());
      break;
    case ShadingMode::Depth: {
      const double d = (hit.position - frame.eye).dot(frame.forward);
      const double g = 1.0 - std::clamp((d - frame.depthNear) / (frame.depthFar - frame.depthNear), 0.0, 1.0);
      out.rgb = Vec3::Constant(0.05 + 0.95 * g);
      break;
    }
    case ShadingMode::Curvature:
      out.rgb = Vec3::Zero();  // coloured per pixel after rendering
      break;
    case ShadingMode::Isophotes: {
      const double nl = std::max(0.0, n.dot(frame.keyLight));
      const int band = std::min(options.isophoteBands - 1, static_cast<int>(nl * options.isophoteBands));
      const Vec3 base = front ? kBase : kBackBase;
      out.rgb = (band & 1) ? Vec3(0.08 * base) : Vec3((0.35 + 0.65 * nl) * base);
      break;
    }
  }
  out.rgb = out.rgb.cwiseMax(0.0).cwiseMin(1.0);
  return out;
}

}  // namespace cip::raycast
