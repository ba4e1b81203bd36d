// Lewiner's marching cubes (scikit-image's algorithm): closed, consistently oriented meshes with the right
// Euler characteristic on a sampled sphere and torus, also with step 2 and Lorensen's table; closed meshes
// through the ambiguous cases and interior vertices of random data; edge vertices at the linear crossing;
// orientation for both gradient directions; the same mesh from any memory layout and sample type; masks and
// errors.
#include "cip/mesh/lewiner_marching_cubes.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <map>
#include <random>
#include <utility>

#include "cip/core/error.h"

using namespace cip;

namespace {

/// Samples f(i, j, k) (array indices) into a C-ordered float32 array.
struct Volume {
  std::array<std::int64_t, 3> shape;
  std::vector<float> data;

  Volume(std::array<std::int64_t, 3> s, const std::function<double(double, double, double)>& f) : shape(s) {
    data.resize(static_cast<std::size_t>(s[0] * s[1] * s[2]));
    for (std::int64_t i = 0; i < s[0]; ++i)
      for (std::int64_t j = 0; j < s[1]; ++j)
        for (std::int64_t k = 0; k < s[2]; ++k)
          data[static_cast<std::size_t>((i * s[1] + j) * s[2] + k)] =
              static_cast<float>(f(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
  }
  StridedSamples view() const {
    StridedSamples v;
    v.data = data.data();
    v.shape = shape;
    v.strides = {static_cast<std::int64_t>(4 * shape[1] * shape[2]), static_cast<std::int64_t>(4 * shape[2]),
                 4};
    v.type = ElementType::Float32;
    return v;
  }
  float at(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return data[static_cast<std::size_t>((i * shape[1] + j) * shape[2] + k)];
  }
};

Volume sphere(int n, double radius) {
  const double c = 0.5 * (n - 1) + 0.123;
  return Volume({n, n, n}, [=](double x, double y, double z) {
    return radius - std::sqrt((x - c) * (x - c) + (y - c) * (y - c) + (z - c) * (z - c));
  });
}

Volume torus(int n) {
  const double c = 0.5 * (n - 1) + 0.071, big = 0.28 * n, small = 0.11 * n;
  return Volume({n, n, n}, [=](double x, double y, double z) {
    const double r = std::sqrt((x - c) * (x - c) + (y - c) * (y - c)) - big;
    return small - std::sqrt(r * r + (z - c) * (z - c));
  });
}

struct Topology {
  bool closed = true;    ///< every undirected edge in exactly two triangles
  bool oriented = true;  ///< every directed edge at most once
  std::int64_t euler = 0;
  std::size_t unused = 0;  ///< vertices no face uses
};

Topology topology(const LewinerMesh& m) {
  std::map<std::pair<std::int32_t, std::int32_t>, int> directed;
  std::vector<char> used(m.vertices.size(), 0);
  for (const auto& f : m.faces)
    for (int k = 0; k < 3; ++k) {
      ++directed[{f[k], f[(k + 1) % 3]}];
      used[static_cast<std::size_t>(f[k])] = 1;
    }
  Topology t;
  std::int64_t edges = 0;
  for (const auto& [e, count] : directed) {
    if (count != 1) t.oriented = false;
    const auto back = directed.find({e.second, e.first});
    if (back == directed.end() || back->second != count) t.closed = false;
    if (e.first < e.second) edges += count;
  }
  for (char u : used) t.unused += u ? 0 : 1;
  t.euler = static_cast<std::int64_t>(m.vertices.size() - t.unused) - edges +
            static_cast<std::int64_t>(m.faces.size());
  return t;
}

double signedVolume(const LewinerMesh& m) {
  double v = 0;
  for (const auto& f : m.faces) {
    const auto& a = m.vertices[static_cast<std::size_t>(f[0])];
    const auto& b = m.vertices[static_cast<std::size_t>(f[1])];
    const auto& c = m.vertices[static_cast<std::size_t>(f[2])];
    v += (double(a[0]) * (double(b[1]) * c[2] - double(b[2]) * c[1]) -
          double(a[1]) * (double(b[0]) * c[2] - double(b[2]) * c[0]) +
          double(a[2]) * (double(b[0]) * c[1] - double(b[1]) * c[0])) /
         6.0;
  }
  return v;
}

LewinerOptions options(double level = 0.0, int step = 1, bool classic = false) {
  LewinerOptions o;
  o.level = level;
  o.stepSize = step;
  o.classic = classic;
  return o;
}

}  // namespace

TEST(LewinerMarchingCubes, SphereIsClosedWithEulerCharacteristicTwo) {
  const Volume v = sphere(32, 11.3);
  for (bool classic : {false, true})
    for (int step : {1, 2}) {
      const LewinerMesh m = lewinerMarchingCubes(v.view(), options(0.0, step, classic));
      ASSERT_GT(m.faces.size(), 100u);
      const Topology t = topology(m);
      EXPECT_TRUE(t.closed) << "classic " << classic << " step " << step;
      EXPECT_TRUE(t.oriented);
      EXPECT_EQ(t.unused, 0u);
      EXPECT_EQ(t.euler, 2);
      // The enclosed volume approaches the ball's (the mesh is inscribed; coarser with step 2).
      const double ball = 4.0 / 3.0 * M_PI * std::pow(11.3, 3);
      EXPECT_NEAR(std::abs(signedVolume(m)) / ball, 1.0, step == 1 ? 0.02 : 0.06);
    }
}

TEST(LewinerMarchingCubes, TorusIsClosedWithEulerCharacteristicZero) {
  const Volume v = torus(40);
  const LewinerMesh m = lewinerMarchingCubes(v.view(), options());
  const Topology t = topology(m);
  EXPECT_TRUE(t.closed);
  EXPECT_TRUE(t.oriented);
  EXPECT_EQ(t.euler, 0);
}

TEST(LewinerMarchingCubes, EdgeVerticesSitAtTheLinearCrossing) {
  const Volume v = torus(30);
  const double level = 0.25;
  const LewinerMesh m = lewinerMarchingCubes(v.view(), options(level));
  ASSERT_FALSE(m.vertices.empty());
  for (const auto& p : m.vertices) {
    int along = -1, integral = 0;
    std::array<std::int64_t, 3> lo{};
    for (int a = 0; a < 3; ++a) {
      const double f = std::floor(p[a]);
      lo[a] = static_cast<std::int64_t>(f);
      if (p[a] == f)
        ++integral;
      else
        along = a;
    }
    ASSERT_GE(integral, 2) << "vertex off the grid edges (" << p[0] << ", " << p[1] << ", " << p[2] << ")";
    if (along < 0) continue;  // on a sample
    std::array<std::int64_t, 3> hi = lo;
    ++hi[along];
    const double a = v.at(lo[0], lo[1], lo[2]) - level, b = v.at(hi[0], hi[1], hi[2]) - level;
    ASSERT_LT(a * b, 0.0) << "no sign change on the vertex's edge";
    EXPECT_NEAR(p[along] - static_cast<float>(lo[along]), a / (a - b), 2e-5);
  }
}

TEST(LewinerMarchingCubes, RandomDataThroughAmbiguousCasesStaysClosed) {
  // Noise at the grid's scale hits the ambiguous cases (3, 4, 6, 7, 10, 12, 13) and their interior vertices;
  // a negative border closes the surface.
  std::mt19937 random(7);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  const int n = 14;
  Volume v({n, n, n}, [&](double x, double y, double z) {
    const bool border = x == 0 || y == 0 || z == 0 || x == n - 1 || y == n - 1 || z == n - 1;
    return border ? -1.0 : uniform(random);
  });
  const LewinerMesh m = lewinerMarchingCubes(v.view(), options());
  const Topology t = topology(m);
  EXPECT_TRUE(t.closed);
  EXPECT_TRUE(t.oriented);
  std::size_t interior = 0;
  for (const auto& p : m.vertices) {
    int integral = 0;
    for (int a = 0; a < 3; ++a) integral += p[a] == std::floor(p[a]) ? 1 : 0;
    interior += integral < 2 ? 1 : 0;
  }
  EXPECT_GT(interior, 0u) << "no interior vertex: the data did not reach the tilings that need one";
}

TEST(LewinerMarchingCubes, GradientDirectionSetsTheWinding) {
  const Volume v = sphere(24, 8.2);  // higher values inside
  LewinerOptions o = options();
  const LewinerMesh descent = lewinerMarchingCubes(v.view(), o);
  o.descent = false;
  const LewinerMesh ascent = lewinerMarchingCubes(v.view(), o);
  ASSERT_EQ(descent.faces.size(), ascent.faces.size());
  // Vertex normals point to lower values (outwards); 'ascent' faces wind counter-clockwise seen from there.
  EXPECT_GT(signedVolume(ascent), 0.0);
  EXPECT_NEAR(signedVolume(descent), -signedVolume(ascent), 1e-9 * signedVolume(ascent));
  const auto& p = ascent.vertices[0];
  const double c = 0.5 * 23 + 0.123;
  const auto& normal = ascent.normals[0];
  EXPECT_GT((p[0] - c) * normal[0] + (p[1] - c) * normal[1] + (p[2] - c) * normal[2], 0.0);
}

TEST(LewinerMarchingCubes, AnyLayoutAndIntegerTypeGivesTheSameMesh) {
  const Volume v = torus(20);
  const LewinerMesh reference = lewinerMarchingCubes(v.view(), options(0.5));
  // Fortran order: the same samples, axis 0 fastest.
  std::vector<double> fortran(v.data.size());
  const auto& s = v.shape;
  for (std::int64_t i = 0; i < s[0]; ++i)
    for (std::int64_t j = 0; j < s[1]; ++j)
      for (std::int64_t k = 0; k < s[2]; ++k)
        fortran[static_cast<std::size_t>(i + s[0] * (j + s[1] * k))] = v.at(i, j, k);
  StridedSamples f;
  f.data = fortran.data();
  f.shape = s;
  f.strides = {8, 8 * s[0], 8 * s[0] * s[1]};
  f.type = ElementType::Float64;
  const LewinerMesh other = lewinerMarchingCubes(f, options(0.5));
  EXPECT_EQ(other.vertices, reference.vertices);
  EXPECT_EQ(other.faces, reference.faces);
  EXPECT_EQ(other.normals, reference.normals);
  EXPECT_EQ(other.values, reference.values);
  // int16 samples convert exactly: the same mesh as from their float copy.
  std::vector<std::int16_t> ints(v.data.size());
  Volume asFloat = v;
  for (std::size_t i = 0; i < ints.size(); ++i) {
    ints[i] = static_cast<std::int16_t>(std::lround(20 * v.data[i]));
    asFloat.data[i] = ints[i];
  }
  StridedSamples iv = v.view();
  iv.data = ints.data();
  iv.strides = {2 * s[1] * s[2], 2 * s[2], 2};
  iv.type = ElementType::Int16;
  EXPECT_EQ(lewinerMarchingCubes(iv, options(3.5)).faces,
            lewinerMarchingCubes(asFloat.view(), options(3.5)).faces);
}

TEST(LewinerMarchingCubes, ThreadCountDoesNotChangeTheMesh) {
  // Noise through every case, with enough layers for many slabs: the slabs' shared planes, their vertices'
  // normals (float sums in the serial order) and values must come out as the serial walk's.
  std::mt19937 random(11);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  const Volume v({90, 17, 13}, [&](double, double, double) { return uniform(random); });
  for (bool classic : {false, true}) {
    LewinerOptions o = options(0.1, 1, classic);
    o.threads = 1;
    const LewinerMesh serial = lewinerMarchingCubes(v.view(), o);
    for (int threads : {0, 2, 3}) {
      o.threads = threads;
      const LewinerMesh parallel = lewinerMarchingCubes(v.view(), o);
      EXPECT_EQ(parallel.vertices, serial.vertices);
      EXPECT_EQ(parallel.faces, serial.faces);
      EXPECT_EQ(parallel.normals, serial.normals);
      EXPECT_EQ(parallel.values, serial.values);
    }
  }
}

TEST(LewinerMarchingCubes, MaskLimitsTheCells) {
  const Volume v = sphere(24, 8.2);
  std::vector<unsigned char> mask(v.data.size(), 0);
  for (std::size_t i = 0; i < mask.size() / 2; ++i) mask[i] = 1;  // axis 0 < 12
  StridedSamples m = v.view();
  m.data = mask.data();
  m.strides = {v.shape[1] * v.shape[2], v.shape[2], 1};
  m.type = ElementType::Bool;
  LewinerOptions o = options();
  o.mask = &m;
  const LewinerMesh half = lewinerMarchingCubes(v.view(), o);
  const LewinerMesh full = lewinerMarchingCubes(v.view(), options());
  ASSERT_FALSE(half.faces.empty());
  EXPECT_LT(half.faces.size(), full.faces.size());
  // A cell is kept when its far corner (axis 0 index + 1) is in the mask, so every vertex has axis 0 <= 11.
  for (const auto& p : half.vertices) EXPECT_LE(p[0], 11.0f);
  EXPECT_FALSE(topology(half).closed);
}

TEST(LewinerMarchingCubes, DegenerateFacesAreRemoved) {
  // Integer samples equal to the level put vertices on samples, where triangles collapse.
  Volume v({12, 12, 12}, [](double x, double y, double z) {
    return std::round(4.2 - std::sqrt((x - 5.5) * (x - 5.5) + (y - 5.3) * (y - 5.3) + (z - 5.6) * (z - 5.6)));
  });
  LewinerMesh m = lewinerMarchingCubes(v.view(), options(0.0));
  const auto degenerate = [](const LewinerMesh& mesh) {
    std::size_t count = 0;
    for (const auto& f : mesh.faces)
      count +=
          (mesh.vertices[static_cast<std::size_t>(f[0])] == mesh.vertices[static_cast<std::size_t>(f[1])] ||
           mesh.vertices[static_cast<std::size_t>(f[1])] == mesh.vertices[static_cast<std::size_t>(f[2])] ||
           mesh.vertices[static_cast<std::size_t>(f[0])] == mesh.vertices[static_cast<std::size_t>(f[2])])
              ? 1
              : 0;
    return count;
  };
  const std::size_t before = degenerate(m), faces = m.faces.size();
  ASSERT_GT(before, 0u);
  removeDegenerateFaces(m);
  EXPECT_EQ(degenerate(m), 0u);
  EXPECT_EQ(m.faces.size(), faces - before);
  EXPECT_EQ(m.normals.size(), m.vertices.size());
  for (std::size_t i = 0; i < m.vertices.size(); ++i)
    for (std::size_t j = i + 1; j < m.vertices.size(); ++j) EXPECT_NE(m.vertices[i], m.vertices[j]);
}

TEST(LewinerMarchingCubes, BadInputThrows) {
  const Volume flat({4, 1, 4}, [](double, double, double) { return 0.0; });
  EXPECT_THROW(lewinerMarchingCubes(flat.view(), options()), Error);
  const Volume v = sphere(8, 2.5);
  EXPECT_THROW(lewinerMarchingCubes(v.view(), options(0.0, 0)), Error);
  StridedSamples wrongMask = flat.view();
  LewinerOptions o = options();
  o.mask = &wrongMask;
  EXPECT_THROW(lewinerMarchingCubes(v.view(), o), Error);
  // A step larger than the volume leaves no cell: an empty mesh, not a crash.
  EXPECT_TRUE(lewinerMarchingCubes(v.view(), options(0.0, 9)).faces.empty());
}
