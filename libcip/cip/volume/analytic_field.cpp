#include "cip/volume/analytic_field.h"

#include <tbb/parallel_for.h>

#include <cmath>

#include "cip/core/error.h"

namespace cip {

namespace {

/// sqrt(a^2 + b^2) for the fields' coordinates (of order 1: no overflow to guard against, so not std::hypot,
/// which costs several times more and dominated the exact-mode builds).
double planeLength(double a, double b) {
  return std::sqrt(a * a + b * b);
}

constexpr double kPi = 3.14159265358979323846;

class Sphere : public AnalyticField {
 public:
  std::string name() const override { return "sphere"; }
  double value(const Vec3& p) const override { return p.norm() - 0.75; }
  void valuesOnLattice(const double* x, const double* y, const double* z, const std::array<int, 3>& count,
                       const std::array<int, 3>& stride, double* out) const override {
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a) {
        const double planar = x[a] * x[a] + y[b] * y[b];
        for (int d = 0; d < count[2]; ++d)
          out[a * stride[0] + b * stride[1] + d * stride[2]] = std::sqrt(planar + z[d] * z[d]) - 0.75;
      }
  }
  Vec3 gradient(const Vec3& p) const override {
    double n = p.norm();
    return n > 0 ? Vec3(p / n) : Vec3::UnitX();
  }
};

class Torus : public AnalyticField {
 public:
  std::string name() const override { return "torus"; }
  static constexpr double R = 0.6, r = 0.25;
  double value(const Vec3& p) const override {
    double q = planeLength(p.x(), p.y()) - R;
    return planeLength(q, p.z()) - r;
  }
  void valuesOnLattice(const double* x, const double* y, const double* z, const std::array<int, 3>& count,
                       const std::array<int, 3>& stride, double* out) const override {
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a) {
        const double q = planeLength(x[a], y[b]) - R;
        for (int d = 0; d < count[2]; ++d)
          out[a * stride[0] + b * stride[1] + d * stride[2]] = planeLength(q, z[d]) - r;
      }
  }
  Vec3 gradient(const Vec3& p) const override {
    double rho = planeLength(p.x(), p.y());
    double q = rho - R, d = planeLength(q, p.z());
    if (rho == 0 || d == 0) return Vec3::UnitZ();
    return Vec3(q / d * p.x() / rho, q / d * p.y() / rho, p.z() / d);
  }
};

class Gyroid : public AnalyticField {
 public:
  std::string name() const override { return "gyroid"; }
  static constexpr double k = 2 * kPi;
  double value(const Vec3& p) const override {
    double x = k * p.x(), y = k * p.y(), z = k * p.z();
    return std::sin(x) * std::cos(y) + std::sin(y) * std::cos(z) + std::sin(z) * std::cos(x);
  }
  /// Six sines and cosines per lattice line instead of per point.
  void valuesOnLattice(const double* x, const double* y, const double* z, const std::array<int, 3>& count,
                       const std::array<int, 3>& stride, double* out) const override {
    std::vector<double> trig(2 * static_cast<std::size_t>(count[0] + count[1] + count[2]));
    double* s[3];
    double* c[3];
    const double* coordinate[3] = {x, y, z};
    double* next = trig.data();
    for (int axis = 0; axis < 3; ++axis) {
      s[axis] = next;
      c[axis] = next + count[axis];
      next += 2 * count[axis];
      for (int i = 0; i < count[axis]; ++i) {
        s[axis][i] = std::sin(k * coordinate[axis][i]);
        c[axis][i] = std::cos(k * coordinate[axis][i]);
      }
    }
    for (int d = 0; d < count[2]; ++d)
      for (int b = 0; b < count[1]; ++b)
        for (int a = 0; a < count[0]; ++a)
          out[a * stride[0] + b * stride[1] + d * stride[2]] =
              s[0][a] * c[1][b] + s[1][b] * c[2][d] + s[2][d] * c[0][a];
  }
  Vec3 gradient(const Vec3& p) const override {
    double x = k * p.x(), y = k * p.y(), z = k * p.z();
    return k * Vec3(std::cos(x) * std::cos(y) - std::sin(z) * std::sin(x),
                    -std::sin(x) * std::sin(y) + std::cos(y) * std::cos(z),
                    -std::sin(y) * std::sin(z) + std::cos(z) * std::cos(x));
  }
};

class MarschnerLobb : public AnalyticField {
 public:
  std::string name() const override { return "marschner-lobb"; }
  double defaultIsovalue() const override { return 0.5; }
  static constexpr double fM = 6, alpha = 0.25;
  double value(const Vec3& p) const override {
    double r = planeLength(p.x(), p.y());
    double rhoR = std::cos(2 * kPi * fM * std::cos(kPi * r / 2));
    return (1 - std::sin(kPi * p.z() / 2) + alpha * (1 + rhoR)) / (2 * (1 + alpha));
  }
  /// The radial term once per (x, y), the axial one once per z.
  void valuesOnLattice(const double* x, const double* y, const double* z, const std::array<int, 3>& count,
                       const std::array<int, 3>& stride, double* out) const override {
    std::vector<double> axial(static_cast<std::size_t>(count[2]));
    for (int d = 0; d < count[2]; ++d) axial[d] = std::sin(kPi * z[d] / 2);
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a) {
        const double rhoR = std::cos(2 * kPi * fM * std::cos(kPi * planeLength(x[a], y[b]) / 2));
        for (int d = 0; d < count[2]; ++d)
          out[a * stride[0] + b * stride[1] + d * stride[2]] =
              (1 - axial[d] + alpha * (1 + rhoR)) / (2 * (1 + alpha));
      }
  }
  Vec3 gradient(const Vec3& p) const override {
    double r = planeLength(p.x(), p.y());
    // d rhoR / dr = sin(2 pi fM cos(pi r / 2)) * 2 pi fM * sin(pi r / 2) * pi / 2 ... with sign:
    // rhoR = cos(u), u = 2 pi fM cos(pi r/2); du/dr = -2 pi fM sin(pi r/2) pi/2; drhoR/dr = -sin(u) du/dr.
    double u = 2 * kPi * fM * std::cos(kPi * r / 2);
    double dudr = -2 * kPi * fM * std::sin(kPi * r / 2) * kPi / 2;
    double drho = -std::sin(u) * dudr;
    double s = alpha / (2 * (1 + alpha));
    Vec3 g(0, 0, -std::cos(kPi * p.z() / 2) * kPi / 2 / (2 * (1 + alpha)));
    if (r > 0) {
      g.x() = s * drho * p.x() / r;
      g.y() = s * drho * p.y() / r;
    }
    return g;
  }
};

class Plane : public AnalyticField {
 public:
  std::string name() const override { return "plane"; }
  double value(const Vec3& p) const override { return normal().dot(p) - 0.05; }
  Vec3 gradient(const Vec3&) const override { return normal(); }
  static Vec3 normal() { return Vec3(0.3, -0.5, 0.81); }
};

}  // namespace

std::vector<std::string> analyticFieldNames() {
  return {"sphere", "torus", "gyroid", "marschner-lobb", "plane"};
}

std::unique_ptr<AnalyticField> makeAnalyticField(const std::string& name) {
  if (name == "sphere") return std::make_unique<Sphere>();
  if (name == "torus") return std::make_unique<Torus>();
  if (name == "gyroid") return std::make_unique<Gyroid>();
  if (name == "marschner-lobb") return std::make_unique<MarschnerLobb>();
  if (name == "plane") return std::make_unique<Plane>();
  return nullptr;
}

double marschnerLobbRippleFrequency(const Vec3& p) {
  // The ripple is cos(2 pi u) with u = f_M cos(pi r / 2) cycles; its frequency is |du/dr|.
  return MarschnerLobb::fM * kPi / 2 * std::abs(std::sin(kPi * planeLength(p.x(), p.y()) / 2));
}

DenseGrid sampleField(const ScalarField& field, int resolution, const std::string& description) {
  if (resolution < 1 || resolution > 4096)
    throw Error("resolution must be between 1 and 4096 cells per axis");
  DenseGrid g;
  std::int64_t n = resolution + 1;
  g.allocate({n, n, n});
  g.geometry.origin = Vec3(-1, -1, -1);
  g.geometry.spacing = Vec3::Constant(2.0 / resolution);
  g.description = description;
  // World coordinates per axis exactly as indexToWorld computes them for each point.
  std::array<std::vector<double>, 3> coordinate;
  for (int a = 0; a < 3; ++a) {
    coordinate[a].resize(static_cast<std::size_t>(n));
    for (std::int64_t i = 0; i < n; ++i)
      coordinate[a][static_cast<std::size_t>(i)] = g.geometry.origin[a] + g.geometry.spacing[a] * double(i);
  }
  const int m = static_cast<int>(n);
  tbb::parallel_for(std::int64_t(0), n, [&](std::int64_t k) {
    field.valuesOnLattice(coordinate[0].data(), coordinate[1].data(), coordinate[2].data() + k, {m, m, 1},
                          {1, m, 0}, &g.at(0, 0, k));
  });
  return g;
}

}  // namespace cip
