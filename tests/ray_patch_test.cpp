// Ray-patch intersection: the Bernstein root finder against independent oracles (known factored roots, dense
// sampling with long double evaluation plus bisection), edge cases (roots at interval ends, double roots,
// clustered roots, near misses), the cell clip, and real patches of a sampled sphere.
#include "cip/ray/ray_patch.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "cip/model/model_builder.h"
#include "cip/volume/analytic_field.h"
#include "support/sanitized_build.h"

using namespace cip;

namespace {

// A polynomial described independently of RayPolynomial, evaluated in long double by the oracle.
struct SpecTerm {
  double coefficient;
  std::vector<std::pair<LinearFactor, int>> factors;  // (factor, power)
};
struct Spec {
  std::vector<SpecTerm> terms;

  RayPolynomial build() const {
    RayPolynomial p;
    for (const auto& t : terms) {
      int ti = p.addTerm(t.coefficient);
      for (const auto& [f, power] : t.factors) p.multiplyTerm(ti, p.addFactor(f), power);
    }
    return p;
  }
  long double value(long double t) const {
    long double sum = 0;
    for (const auto& term : terms) {
      long double r = term.coefficient;
      for (const auto& [f, power] : term.factors)
        for (int k = 0; k < power; ++k)
          r *= static_cast<long double>(f.offset) + static_cast<long double>(f.slope) * t;
      sum += r;
    }
    return sum;
  }
};

// First sign change (or exact zero) of spec on [a,b] by dense sampling, refined by bisection in long double.
std::optional<double> oracleFirstRoot(const Spec& spec, double a, double b, int samples = 20000) {
  long double prevT = a, prevV = spec.value(a);
  if (prevV == 0) return a;
  for (int i = 1; i <= samples; ++i) {
    long double t = a + (static_cast<long double>(b) - a) * i / samples;
    long double v = spec.value(t);
    if (v == 0) return static_cast<double>(t);
    if ((v < 0) != (prevV < 0)) {
      long double lo = prevT, hi = t, vlo = prevV;
      for (int k = 0; k < 200; ++k) {
        long double m = 0.5L * (lo + hi), vm = spec.value(m);
        if (vm == 0) return static_cast<double>(m);
        if ((vm < 0) == (vlo < 0)) {
          lo = m;
          vlo = vm;
        } else {
          hi = m;
        }
      }
      return static_cast<double>(0.5L * (lo + hi));
    }
    prevT = t;
    prevV = v;
  }
  return std::nullopt;
}

// Product c * prod (slope_i t - slope_i r_i): roots r_i with varied slopes.
SpecTerm productWithRoots(double c, const std::vector<double>& roots, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> slope(0.3, 3.0);
  std::bernoulli_distribution flip(0.5);
  SpecTerm term{c, {}};
  for (double r : roots) {
    double s = slope(rng) * (flip(rng) ? -1 : 1);
    term.factors.push_back({LinearFactor{-s * r, s}, 1});
  }
  return term;
}

double binomial(int n, int k) {
  double r = 1;
  for (int i = 1; i <= k; ++i) r = r * (n - k + i) / i;
  return r;
}

}  // namespace

TEST(RayPolynomial, BernsteinMatchesFactoredValue) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  Spec spec;
  for (int t = 0; t < 3; ++t) {
    SpecTerm term{u(rng), {}};
    for (int k = 0; k < 4 + 3 * t; ++k) term.factors.push_back({LinearFactor{u(rng), u(rng)}, 1 + (k % 2)});
    spec.terms.push_back(term);
  }
  RayPolynomial p = spec.build();
  std::array<double, RayPolynomial::kMaxDegree + 1> b;
  const double lo = -0.4, hi = 1.3;
  int n = p.bernstein(lo, hi, b);
  EXPECT_EQ(n, p.degree());
  EXPECT_EQ(b[0], p.value(lo));  // end coefficients are the factored values, bit for bit
  EXPECT_EQ(b[n], p.value(hi));
  for (double s : {0.1, 0.37, 0.5, 0.81}) {
    long double sum = 0;
    for (int k = 0; k <= n; ++k) sum += b[k] * binomial(n, k) * std::pow(1 - s, n - k) * std::pow(s, k);
    double t = lo + s * (hi - lo);
    EXPECT_NEAR(static_cast<double>(sum), static_cast<double>(spec.value(t)), 1e-12);
    double v, d;
    p.valueAndDerivative(t, v, d);
    const double h = 1e-6;
    EXPECT_NEAR(d, static_cast<double>((spec.value(t + h) - spec.value(t - h)) / (2 * h)),
                1e-6 * (1 + std::abs(d)));
  }
}

TEST(FirstRoot, ClusteredRootsOfDegree24Product) {
  std::mt19937_64 rng(11);
  std::vector<double> roots;
  for (int k = 0; k < 12; ++k) roots.push_back(0.4 + 1e-6 * k);  // a tight cluster
  for (int k = 0; k < 12; ++k) roots.push_back(-2.0 - 0.1 * k);  // outside the interval
  Spec spec{{productWithRoots(1.0, roots, rng)}};
  RayPolynomial p = spec.build();
  ASSERT_EQ(p.degree(), 24);
  for (int start = 0; start < 12; ++start) {
    // Start just after root `start - 1`: the first root is `start`.
    double a = start == 0 ? 0.0 : 0.4 + 1e-6 * (start - 0.5);
    auto r = firstRoot(p, a, 1.0);
    ASSERT_TRUE(r) << start;
    EXPECT_NEAR(r->t, 0.4 + 1e-6 * start, 1e-14) << start;
    EXPECT_EQ(r->kind, RootKind::Bracketed);
  }
  EXPECT_FALSE(firstRoot(p, 0.40002, 1.0));
}

TEST(FirstRoot, RandomSumsOfHighDegreeProductsAgreeWithOracle) {
  std::mt19937_64 rng(2024);
  std::uniform_real_distribution<double> root(-0.5, 1.5), coef(-1, 1);
  int withRoot = 0;
  for (int trial = 0; trial < 150; ++trial) {
    Spec spec;
    const int degree = 6 + trial % 7;  // 6..12 per product
    for (int t = 0; t < 2; ++t) {
      std::vector<double> roots;
      for (int k = 0; k < degree; ++k) roots.push_back(root(rng));
      spec.terms.push_back(productWithRoots(coef(rng), roots, rng));
    }
    RayPolynomial p = spec.build();
    auto ours = firstRoot(p, 0.0, 1.0);
    auto oracle = oracleFirstRoot(spec, 0.0, 1.0);
    if (oracle) {
      ++withRoot;
      ASSERT_TRUE(ours) << "trial " << trial << " missed root at " << *oracle;
      if (ours->t < *oracle - 1e-9) {
        // Dense sampling can step over a close pair of roots: ours must then be a genuine zero.
        EXPECT_LE(std::abs(static_cast<double>(spec.value(ours->t))), 1e3 * p.roundingBound(ours->t))
            << trial;
      } else {
        EXPECT_NEAR(ours->t, *oracle, 1e-12 * (1 + std::abs(*oracle))) << "trial " << trial;
      }
    } else if (ours) {
      // No sign change seen by the oracle: ours must be a touch or a close pair the sampling stepped over.
      EXPECT_LE(std::abs(static_cast<double>(spec.value(ours->t))), 1e3 * p.roundingBound(ours->t)) << trial;
    }
  }
  EXPECT_GT(withRoot, 50);
}

// The interval bound firstRoot checks first: whenever it excludes zero on [a, b], the polynomial (in long
// double, densely sampled) keeps one strict sign there, also for squared factors that change sign and odd and
// even powers; and it never excludes an interval holding a root. It must also decide often enough to pay.
TEST(RayPolynomial, ExcludesZeroOnlyWhereThereIsNoZero) {
  std::mt19937_64 rng(77);
  std::uniform_real_distribution<double> root(-0.5, 1.5), coef(-1, 1), end(0, 1);
  std::uniform_int_distribution<int> power(1, 3);
  int excluded = 0, intervals = 0;
  for (int trial = 0; trial < 400; ++trial) {
    Spec spec;
    for (int t = 0; t < 3; ++t) {
      SpecTerm term{coef(rng), {}};
      for (int k = 0; k < 3; ++k) {
        const double r = root(rng), slope = coef(rng);
        term.factors.push_back({LinearFactor{-slope * r + 0.3 * coef(rng), slope}, power(rng)});
      }
      spec.terms.push_back(term);
    }
    const RayPolynomial p = spec.build();
    for (int k = 0; k < 5; ++k) {
      double a = end(rng), b = end(rng);
      if (a > b) std::swap(a, b);
      if (k == 0) b = a + 1e-3 * (b - a);  // short intervals are decided most often
      ++intervals;
      const auto oracle = oracleFirstRoot(spec, a, b, 2000);
      if (!p.excludesZero(a, b)) continue;
      ++excluded;
      ASSERT_FALSE(oracle) << "trial " << trial << ": a zero at " << *oracle << " in [" << a << ", " << b
                           << "]";
      ASSERT_FALSE(firstRoot(p, a, b)) << trial;
    }
  }
  std::printf("%d of %d intervals excluded\n", excluded, intervals);
  EXPECT_GT(excluded, intervals / 10);
  // Identically zero: never excluded. A constant: excluded.
  const Spec zero{{SpecTerm{0.0, {{LinearFactor{1, 1}, 1}}}}}, constant{{SpecTerm{2.0, {}}}};
  EXPECT_FALSE(zero.build().excludesZero(0, 1));
  EXPECT_TRUE(constant.build().excludesZero(0, 1));
}

TEST(FirstRoot, RootsAtIntervalEnds) {
  // (t - 0.25)(t - 2): root exactly at 0.25 (representable).
  Spec spec{{SpecTerm{1.0, {{LinearFactor{-0.25, 1}, 1}, {LinearFactor{-2, 1}, 1}}}}};
  RayPolynomial p = spec.build();
  auto entry = firstRoot(p, 0.25, 1.0);
  ASSERT_TRUE(entry);
  EXPECT_EQ(entry->t, 0.25);
  EXPECT_EQ(entry->kind, RootKind::EndPoint);
  auto exit = firstRoot(p, 0.0, 0.25);  // the exit end must not be missed
  ASSERT_TRUE(exit);
  EXPECT_EQ(exit->t, 0.25);
  EXPECT_EQ(exit->kind, RootKind::EndPoint);
  // Exit-end root of a high-degree sum whose other coefficients are all positive.
  Spec sum{{SpecTerm{1.0, {{LinearFactor{0.5, -1}, 1}, {LinearFactor{1, 1}, 8}}},
            SpecTerm{2.0, {{LinearFactor{0.5, -1}, 3}, {LinearFactor{3, -1}, 4}}}}};
  RayPolynomial q = sum.build();
  auto r = firstRoot(q, 0.0, 0.5);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->t, 0.5);
  // Root at the exit end with an interior root before it: the interior one is first.
  Spec two{{SpecTerm{1.0, {{LinearFactor{-0.5, 1}, 1}, {LinearFactor{-1.0 / 3.0, 1}, 1}}}}};
  auto r2 = firstRoot(two.build(), 0.0, 0.5);
  ASSERT_TRUE(r2);
  EXPECT_NEAR(r2->t, 1.0 / 3.0, 1e-15);
  // A root at the end shared by two adjacent intervals is found by both.
  auto left = firstRoot(p, -1.0, 0.25), right = firstRoot(p, 0.25, 0.9);
  ASSERT_TRUE(left && right);
  EXPECT_EQ(left->t, right->t);
}

TEST(FirstRoot, DoubleRootsAreTouches) {
  std::mt19937_64 rng(3);
  // Factored double root: (t - 0.3)^2 (t - 0.8)(t + 2).
  Spec spec{
      {SpecTerm{1.0, {{LinearFactor{-0.3, 1}, 2}, {LinearFactor{-0.8, 1}, 1}, {LinearFactor{2, 1}, 1}}}}};
  RayPolynomial p = spec.build();
  auto r = firstRoot(p, 0.0, 1.0);
  ASSERT_TRUE(r);
  EXPECT_NEAR(r->t, 0.3, 1e-14);
  EXPECT_EQ(r->kind, RootKind::Touch);
  // Double root of a sum: (t - a)(t - b) + (b - a)^2 / 4 touches zero at (a + b) / 2. With dyadic a, b
  // everything is exact and the touch must be found.
  for (double a : {0.125, 0.25, 0.5}) {
    const double b = a + 0.5, c = (b - a) * (b - a) / 4;
    Spec touch{{SpecTerm{1.0, {{LinearFactor{-a, 1}, 1}, {LinearFactor{-b, 1}, 1}}}, SpecTerm{c, {}}}};
    auto t = firstRoot(touch.build(), 0.0, 1.0);
    ASSERT_TRUE(t) << a;
    EXPECT_NEAR(t->t, 0.5 * (a + b), 1e-7) << a;
  }
  // With rounded data the minimum lies within rounding of zero on either side: a hit (then at the touch
  // point, to about sqrt(eps)) or a miss are both correct answers; the search must stay cheap.
  for (double a : {0.1, 0.3, 0.6}) {
    const double b = a + 0.3, c = (b - a) * (b - a) / 4;
    Spec touch{{SpecTerm{1.0, {{LinearFactor{-a, 1}, 1}, {LinearFactor{-b, 1}, 1}}}, SpecTerm{c, {}}}};
    RootSearchStats stats;
    auto t = firstRoot(touch.build(), 0.0, 1.0, {}, &stats);
    if (t) {
      EXPECT_NEAR(t->t, 0.5 * (a + b), 1e-7) << a;
    }
    EXPECT_LT(stats.intervals, 500);
  }
  // Even power of a degree-12 product: every root is a touch; the first one is reported.
  std::vector<double> roots{0.15, 0.2, 0.55, 0.9, 1.1, -0.3};
  SpecTerm sq = productWithRoots(1.0, roots, rng);
  for (auto& f : sq.factors) f.second = 2;
  Spec squared{{sq}};
  auto s = firstRoot(squared.build(), 0.0, 1.0);
  ASSERT_TRUE(s);
  EXPECT_NEAR(s->t, 0.15, 1e-13);
  // A triple root changes sign: bracketed.
  Spec triple{{SpecTerm{-2.0, {{LinearFactor{-0.7, 1}, 3}, {LinearFactor{1, 1}, 2}}}}};
  auto t3 = firstRoot(triple.build(), 0.0, 1.0);
  ASSERT_TRUE(t3);
  EXPECT_NEAR(t3->t, 0.7, 1e-5);  // cube-root conditioning
}

TEST(FirstRoot, NearMissesAreMisses) {
  for (double gap : {1e-3, 1e-6, 1e-9, 1e-12}) {
    // (t - 0.5)^2 + gap: minimum `gap` far above rounding (~1e-17 here).
    Spec spec{{SpecTerm{1.0, {{LinearFactor{-0.5, 1}, 2}}}, SpecTerm{gap, {}}}};
    RayPolynomial p = spec.build();
    RootSearchStats stats;
    EXPECT_FALSE(firstRoot(p, 0.0, 1.0, {}, &stats)) << gap;
    EXPECT_EQ(stats.budgetExhausted, 0);
  }
  // Degree 12 sum of squares-like product plus a small positive term: no root, and the search stays small.
  std::mt19937_64 rng(5);
  SpecTerm sq = productWithRoots(1.0, {0.1, 0.3, 0.35, 0.6, 0.61, 0.9}, rng);
  for (auto& f : sq.factors) f.second = 2;
  Spec spec{{sq, SpecTerm{1e-14, {}}}};
  RootSearchStats stats;
  EXPECT_FALSE(firstRoot(spec.build(), 0.0, 1.0, {}, &stats));
  EXPECT_LT(stats.intervals, 2000);
  // Negative gap of the same size: two close roots, both found in order.
  Spec close{{SpecTerm{1.0, {{LinearFactor{-0.5, 1}, 2}}}, SpecTerm{-1e-12, {}}}};
  auto r = firstRoot(close.build(), 0.0, 1.0);
  ASSERT_TRUE(r);
  EXPECT_NEAR(r->t, 0.5 - 1e-6, 1e-12);
}

TEST(FirstCrossing, SkipsEvenMultiplicityZeros) {
  // (t - 0.3)^2 (t - 0.8): the touch at 0.3 is skipped, the crossing at 0.8 found.
  Spec spec{{SpecTerm{1.0, {{LinearFactor{-0.3, 1}, 2}, {LinearFactor{-0.8, 1}, 1}}}}};
  RayPolynomial p = spec.build();
  auto touch = firstRoot(p, 0.0, 1.0);
  ASSERT_TRUE(touch);
  EXPECT_NEAR(touch->t, 0.3, 1e-14);
  auto crossing = firstCrossing(p, 0.0, 1.0);
  ASSERT_TRUE(crossing);
  EXPECT_NEAR(crossing->t, 0.8, 1e-15);
  // A crossing exactly at either end is kept (the sign is tested just beyond the end).
  auto atEnd = firstCrossing(p, 0.5, 0.8);
  ASSERT_TRUE(atEnd);
  EXPECT_EQ(atEnd->t, 0.8);
  auto atStart = firstCrossing(p, 0.8, 1.0);
  ASSERT_TRUE(atStart);
  EXPECT_EQ(atStart->t, 0.8);
  // A touch at the end is not a crossing.
  EXPECT_FALSE(firstCrossing(p, 0.0, 0.3));
  // Identically zero: no crossing.
  Spec zero{{SpecTerm{0.0, {}}}};
  EXPECT_FALSE(firstCrossing(zero.build(), 0.0, 1.0));
}

TEST(FirstCrossing, PatchZerosAtCubeVerticesAndEdgesAreSkipped) {
  auto field = makeAnalyticField("sphere");
  DenseGrid grid = sampleField(*field, 8, "sphere");
  BuildOptions options;
  options.normals = NormalMode::Exact;
  options.exactField = field.get();
  Model model = buildModel(grid, options);
  RootSearchOptions crossings;
  crossings.crossingsOnly = true;
  int checked = 0;
  for (std::size_t c = 0; c < model.cells.size(); ++c) {
    const CornerPatch patch = model.patch(c);
    // Faces x = 0, y = 0 and z = 0 all bounding planes: every term vanishes at the vertex (0,0,0).
    if ((patch.faceMask & 0x15) != 0x15) continue;
    ++checked;
    // A ray through the vertex (0,0,0) diagonally into the cell: value 0 at the vertex, no sign change there.
    EXPECT_EQ(patch.value(Vec3::Zero()), 0.0);
    auto any = intersectRayPatch(patch, Vec3(-0.5, -0.5, -0.5), Vec3(1, 1, 1), 0, 0.5 + 1e-12);
    ASSERT_TRUE(any);
    EXPECT_NE(any->kind, RootKind::Bracketed);
    const double v = patch.value(Vec3::Constant(0.01));
    auto crossing =
        intersectRayPatch(patch, Vec3(-0.5, -0.5, -0.5), Vec3(1, 1, 1), 0, 0.5 + 1e-12, crossings);
    if (crossing) {
      EXPECT_LT(v * patch.value(Vec3::Constant(-0.01)), 0);
    }
  }
  EXPECT_GT(checked, 0);
}

TEST(FirstRoot, DegenerateInputs) {
  Spec zero{{SpecTerm{0.0, {}}}};
  auto r = firstRoot(zero.build(), 0.2, 0.7);  // identically zero: a hit at the start
  ASSERT_TRUE(r);
  EXPECT_EQ(r->t, 0.2);
  Spec constant{{SpecTerm{3.0, {}}}};
  EXPECT_FALSE(firstRoot(constant.build(), 0.0, 1.0));
  EXPECT_FALSE(firstRoot(constant.build(), 1.0, 0.0));
  EXPECT_FALSE(firstRoot(constant.build(), 0.0, std::nan("")));
}

TEST(ClipRayToCell, SlabsAndPadding) {
  double t0, t1;
  ASSERT_TRUE(clipRayToCell(Vec3(-1, 0.5, 0.5), Vec3(1, 0, 0), 0, 10, t0, t1, 0.0));
  EXPECT_DOUBLE_EQ(t0, 1.0);
  EXPECT_DOUBLE_EQ(t1, 2.0);
  ASSERT_TRUE(clipRayToCell(Vec3(-1, 0.5, 0.5), Vec3(1, 0, 0), 1.5, 10, t0, t1, 0.0));
  EXPECT_DOUBLE_EQ(t0, 1.5);
  EXPECT_FALSE(
      clipRayToCell(Vec3(-1, 1.5, 0.5), Vec3(1, 0, 0), 0, 10, t0, t1));  // parallel, outside the slab
  EXPECT_FALSE(clipRayToCell(Vec3(-1, 0.5, 0.5), Vec3(-1, 0, 0), 0, 10, t0, t1));  // pointing away
  // A ray along the shared face y = 1 is kept by the padded box only.
  EXPECT_FALSE(clipRayToCell(Vec3(-1, 1 + 5e-10, 0.5), Vec3(1, 0, 0), 0, 10, t0, t1, 0.0));
  EXPECT_TRUE(clipRayToCell(Vec3(-1, 1 + 5e-10, 0.5), Vec3(1, 0, 0), 0, 10, t0, t1));
  ASSERT_TRUE(clipRayToCell(Vec3(2, 2, 2), Vec3(-1, -1, -1), 0, 10, t0, t1));
  EXPECT_NEAR(t0, 1 - kCellClipPad, 1e-15);
  EXPECT_NEAR(t1, 2 + kCellClipPad, 1e-15);
}

TEST(IntersectRayPatch, PlaneSinglesAreExact) {
  // A one-corner patch with no bounding planes is the corner plane itself.
  CornerPatch patch;
  patch.numCorners = 1;
  patch.point[0] = Vec3(0.5, 0.5, 0.5);
  patch.normal[0] = Vec3(1, 1, 1).normalized();
  patch.weight[0] = 1;
  patch.edge[0] = 0;
  auto r = intersectRayPatch(patch, Vec3(0, 0, 0), Vec3(1, 1, 1), 0, 100);
  ASSERT_TRUE(r);
  EXPECT_NEAR(r->t, 0.5, 1e-15);
  EXPECT_FALSE(intersectRayPatch(patch, Vec3(0, 0, 0), Vec3(1, 1, 1), 0, 0.4));  // tMax before the plane
}

// Real patches: every cell of a sampled sphere (exact normals), several rays per cell through the cell box.
// Roots must be zeros of patch.value and agree with a dense-sampling oracle on patch.value.
TEST(IntersectRayPatch, SpherePatchesAgreeWithDenseSampling) {
  auto field = makeAnalyticField("sphere");
  for (int n : {8, 16}) {
    DenseGrid grid = sampleField(*field, n, "sphere");
    BuildOptions options;
    options.normals = NormalMode::Exact;
    options.exactField = field.get();
    Model model = buildModel(grid, options);
    ASSERT_FALSE(model.cells.empty());
    std::mt19937_64 rng(100 + n);
    std::uniform_real_distribution<double> u(0, 1), dir(-1, 1);
    int hits = 0, rays = 0;
    RootSearchStats stats;
    for (std::size_t c = 0; c < model.cells.size(); ++c) {
      const CornerPatch patch = model.patch(c);
      for (int k = 0; k < 12; ++k) {
        // A ray through a random interior point, starting outside the cell.
        Vec3 d(dir(rng), dir(rng), dir(rng));
        if (d.norm() < 0.1) continue;
        d.normalize();
        Vec3 through(u(rng), u(rng), u(rng));
        Vec3 o = through - 2.0 * d;
        ++rays;
        auto ours = intersectRayPatch(patch, o, d, 0, 10, {}, &stats);
        double t0, t1;
        ASSERT_TRUE(clipRayToCell(o, d, 0, 10, t0, t1));
        auto f = [&](double t) { return patch.value(o + t * d); };
        // Oracle: dense sampling of patch.value along the clipped interval, then bisection.
        std::optional<double> oracle;
        const int samples = test::kSanitizedBuild ? 1000 : 4000;  // most of this test's time
        double prevT = t0, prevV = f(t0);
        if (prevV == 0) oracle = t0;
        for (int i = 1; i <= samples && !oracle; ++i) {
          double t = t0 + (t1 - t0) * i / samples, v = f(t);
          if (v == 0 || (v < 0) != (prevV < 0)) {
            double lo = prevT, hi = t;
            for (int it = 0; it < 100 && v != 0; ++it) {
              double m = 0.5 * (lo + hi);
              if ((f(m) < 0) == (prevV < 0))
                lo = m;
              else
                hi = m;
            }
            oracle = v == 0 ? t : 0.5 * (lo + hi);
          }
          prevT = t;
          prevV = v;
        }
        if (ours) {
          ++hits;
          // A zero of the patch: sign change within a tiny step, or a value at rounding level.
          const Vec3 x = o + ours->t * d;
          const double g = patch.derivatives(x).gradient.norm();
          EXPECT_LE(std::abs(patch.value(x)), 1e-12 * (1 + g)) << "cell " << c;
        }
        if (oracle) {
          ASSERT_TRUE(ours) << "n=" << n << " cell " << c << " ray " << k << " missed root at " << *oracle;
          // An earlier root than the oracle's is a close pair the sampling stepped over (checked to be a zero
          // above).
          if (ours->t >= *oracle - 1e-9) {
            EXPECT_NEAR(ours->t, *oracle, 1e-10) << "n=" << n << " cell " << c;
          }
        }
      }
    }
    EXPECT_GT(hits, rays / 4);
    EXPECT_EQ(stats.budgetExhausted, 0);
  }
}
