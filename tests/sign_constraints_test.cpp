// The lazily checked coefficient of sign_constraints.h: the same value as clamping into the interval of every
// counting sample, every counting sample with the right sign, and the expensive callbacks only where needed.
#include "cip/patch/sign_constraints.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

using namespace cip;

namespace {

struct RandomSamples {
  std::vector<double> r, a, b;
  std::vector<bool> far;
  SignSamples view() const { return {r.data(), a.data(), b.data(), static_cast<int>(r.size())}; }
};

// Samples whose constraints mostly agree (a common feasible coefficient near `centre`), with a few that may
// not; `nearFraction` of them are within the margin.
RandomSamples randomSamples(std::mt19937& rng, int count, double nearFraction) {
  std::uniform_real_distribution<double> u(-1, 1), unit(0, 1);
  const double centre = 2 * u(rng);
  RandomSamples s;
  for (int i = 0; i < count; ++i) {
    const double b = unit(rng) < 0.05 ? 0.0 : unit(rng);
    // The patch a + w b has sign(r) at w = centre for most samples.
    const double r = u(rng);
    double a = -centre * b + (r > 0 ? 1 : -1) * 0.5 * unit(rng) * (b + 0.01);
    if (unit(rng) < 0.03) a = -a;  // an occasional conflicting sample
    s.r.push_back(r);
    s.a.push_back(a);
    s.b.push_back(b);
    s.far.push_back(unit(rng) >= nearFraction);
  }
  return s;
}

}  // namespace

// The vectorised sweep marks exactly the samples whose scalar slack is negative or NaN, including zeros of
// either sign, NaN and infinite values, a below the smallest normal double, and counts that leave a tail
// after the vector lanes and span several words.
TEST(SignConstraints, SweepBitsAreTheScalarSlackTest) {
  std::mt19937 rng(7);
  const double special[] = {0.0,
                            -0.0,
                            1.0,
                            -1.0,
                            std::numeric_limits<double>::quiet_NaN(),
                            std::numeric_limits<double>::infinity(),
                            -std::numeric_limits<double>::infinity(),
                            std::numeric_limits<double>::denorm_min(),
                            -std::numeric_limits<double>::min(),
                            1e300};
  std::uniform_int_distribution<int> pick(0, 9), coin(0, 2);
  std::uniform_real_distribution<double> u(-1, 1);
  auto value = [&] { return coin(rng) == 0 ? special[pick(rng)] : u(rng); };
  for (int count : {0, 1, 3, 63, 64, 65, 130, 259}) {
    for (int trial = 0; trial < 20; ++trial) {
      std::vector<double> r(count), a(count), b(count);
      for (int i = 0; i < count; ++i) {
        r[i] = value();
        a[i] = value();
        b[i] = std::abs(value());
      }
      const double w = trial % 5 == 0 ? special[pick(rng)] : 3 * u(rng);
      const SignSamples s{r.data(), a.data(), b.data(), count};
      std::vector<std::uint64_t> bits((count + 63) / 64, ~std::uint64_t{0});
      const int failures = slackSweep(s, w, bits.data());
      int expected = 0;
      for (int i = 0; i < count; ++i) {
        const bool fails = !(CoefficientInterval::slack(r[i] > 0, a[i], b[i], w) >= 0);
        expected += fails;
        ASSERT_EQ(fails, ((bits[i / 64] >> (i % 64)) & 1) != 0)
            << "count " << count << " sample " << i << ": r " << r[i] << " a " << a[i] << " b " << b[i]
            << " w " << w;
      }
      for (int i = count; i < 64 * static_cast<int>(bits.size()); ++i)
        ASSERT_EQ((bits[i / 64] >> (i % 64)) & 1, 0u);
      EXPECT_EQ(failures, expected);
    }
  }
}

TEST(SignConstraints, SameAsClampingIntoTheWholeInterval) {
  std::mt19937 rng(7);
  int feasible = 0, infeasible = 0, clamped = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    const RandomSamples s = randomSamples(rng, 1 + trial % 300, 0.0);
    const double w = std::uniform_real_distribution<double>(-4, 4)(rng);
    CoefficientInterval all;
    for (std::size_t i = 0; i < s.r.size(); ++i) all.add(s.r[i] > 0, s.a[i], s.b[i]);
    const SignedCoefficient lazy = solveSignConstraints(
        w, s.view(), [](int) { return true; }, [](int) { return false; });
    ASSERT_EQ(lazy.feasible, all.feasible()) << trial;
    if (!all.feasible()) {
      ++infeasible;
      continue;
    }
    ++feasible;
    clamped += all.clamp(w) != w;
    EXPECT_EQ(lazy.value, all.clamp(w)) << trial;
    for (std::size_t i = 0; i < s.r.size(); ++i) {
      const double v = s.a[i] + lazy.value * s.b[i];
      EXPECT_TRUE(v == 0 || (v > 0) == (s.r[i] > 0)) << trial << " sample " << i;
    }
  }
  // The trials exercise all three outcomes.
  EXPECT_GT(feasible, 100);
  EXPECT_GT(infeasible, 100);
  EXPECT_GT(clamped, 100);
}

TEST(SignConstraints, NearSamplesCountOnlyWhenConfirmedFar) {
  std::mt19937 rng(11);
  int confirmations = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    const RandomSamples s = randomSamples(rng, 50 + trial % 100, 0.4);
    const double w = std::uniform_real_distribution<double>(-4, 4)(rng);
    // Near samples with an odd index are confirmed far when asked.
    std::vector<int> asked(s.r.size(), 0);
    const SignedCoefficient lazy = solveSignConstraints(
        w, s.view(), [&](int i) { return static_cast<bool>(s.far[static_cast<std::size_t>(i)]); },
        [&](int i) {
          EXPECT_FALSE(s.far[static_cast<std::size_t>(i)]);
          ++asked[static_cast<std::size_t>(i)];
          ++confirmations;
          return i % 2 == 1;
        });
    for (int k : asked) EXPECT_LE(k, 1);
    if (!lazy.feasible) continue;
    for (std::size_t i = 0; i < s.r.size(); ++i) {
      const double v = s.a[i] + lazy.value * s.b[i];
      const bool right = v == 0 || (v > 0) == (s.r[i] > 0);
      // Far samples and confirmed ones have the right sign; a near one asked and not confirmed may not.
      if (s.far[i] || asked[i] == 0 || i % 2 == 1) {
        EXPECT_TRUE(right) << trial << " sample " << i;
      }
    }
  }
  EXPECT_GT(confirmations, 100);
}

// A solver called again with more samples keeps what it knows of the first ones: with every sample counting
// it gives the clamp into the interval of all of them; with near samples, every callback is asked at most
// once per sample over both calls, the samples that count have the right sign, and every sample left on the
// wrong side is among confirmedNear().
TEST(SignConstraints, MoreSamplesInASecondCall) {
  std::mt19937 rng(13);
  int secondCalls = 0, nearWrong = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    const bool withNear = trial % 2 == 1;
    const RandomSamples s = randomSamples(rng, 20 + trial % 200, withNear ? 0.4 : 0.0);
    const double w = std::uniform_real_distribution<double>(-4, 4)(rng);
    SignSamples first = s.view();
    first.count = std::uniform_int_distribution<int>(1, s.view().count)(rng);
    std::vector<int> askedFar(s.r.size(), 0), askedConfirm(s.r.size(), 0);
    auto far = [&](int i) {
      ++askedFar[static_cast<std::size_t>(i)];
      return static_cast<bool>(s.far[static_cast<std::size_t>(i)]);
    };
    auto confirmFar = [&](int i) {
      ++askedConfirm[static_cast<std::size_t>(i)];
      return i % 2 == 1;
    };
    SignConstraintSolver solver;
    solver.reset();
    if (!solver.solve(w, first, far, confirmFar).feasible) continue;
    const SignedCoefficient both = solver.solve(w, s.view(), far, confirmFar);
    ++secondCalls;
    for (std::size_t i = 0; i < s.r.size(); ++i) {
      EXPECT_LE(askedFar[i], 1) << trial;
      EXPECT_LE(askedConfirm[i], 1) << trial;
    }
    if (!withNear) {
      CoefficientInterval all;
      for (std::size_t i = 0; i < s.r.size(); ++i) all.add(s.r[i] > 0, s.a[i], s.b[i]);
      ASSERT_EQ(both.feasible, all.feasible()) << trial;
      if (both.feasible) {
        EXPECT_EQ(both.value, all.clamp(w)) << trial;
      }
      continue;
    }
    if (!both.feasible) continue;
    int wrong = 0;
    for (std::size_t i = 0; i < s.r.size(); ++i) {
      const double v = s.a[i] + both.value * s.b[i];
      const bool right = v == 0 || (v > 0) == (s.r[i] > 0);
      if (s.far[i] || (askedConfirm[i] && i % 2 == 1)) {
        EXPECT_TRUE(right) << trial << " sample " << i;
      }
      wrong += !right;
    }
    EXPECT_GE(solver.confirmedNear(), wrong) << trial;
    nearWrong += wrong;
  }
  EXPECT_GT(secondCalls, 500);
  EXPECT_GT(nearWrong, 50);
}

TEST(SignConstraints, ExaminesOnlySamplesTheValueFails) {
  // Every sample is met by w = 0 with the margin: neither callback runs and w stays.
  const std::vector<double> r{1, -1, 2}, a{1, -1, 0.5}, b{1, 2, 0};
  int calls = 0;
  const SignedCoefficient out = solveSignConstraints(
      0.0, SignSamples{r.data(), a.data(), b.data(), 3},
      [&](int) {
        ++calls;
        return true;
      },
      [&](int) {
        ++calls;
        return true;
      });
  EXPECT_EQ(calls, 0);
  EXPECT_TRUE(out.feasible);
  EXPECT_EQ(out.value, 0.0);
}

TEST(SignConstraints, ZeroBasisWithTheWrongSignIsInfeasible) {
  const std::vector<double> r{1}, a{-1}, b{0};
  const SignedCoefficient out = solveSignConstraints(
      3.0, SignSamples{r.data(), a.data(), b.data(), 1}, [](int) { return true; }, [](int) { return false; });
  EXPECT_FALSE(out.feasible);
  EXPECT_EQ(out.value, 3.0);
}

// For conflicting samples, fewestViolations finds a coefficient that no other contradicts less (checked
// against every range between breakpoints), the preferred value when that is one of the best, and a
// coefficient that meets every sample when there is one.
TEST(SignConstraints, FewestViolationsIsTheMinimumOverAllRanges) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> unit(0, 1);
  int withConflicts = 0, massDecided = 0;
  // The summed |r| of the counting samples that w contradicts.
  auto contradictedMass = [](const SignSamples& view, const std::vector<std::uint8_t>& counts, double w) {
    double mass = 0;
    for (int i = 0; i < view.count; ++i)
      if (counts[static_cast<std::size_t>(i)] && contradicts(view, i, w)) mass += std::abs(view.r[i]);
    return mass;
  };
  for (int trial = 0; trial < 2000; ++trial) {
    RandomSamples s = randomSamples(rng, 1 + trial % 60, 0.2);
    for (std::size_t i = 0; i < s.r.size(); ++i)
      if (unit(rng) < 0.1) s.a[i] = -s.a[i];  // more conflicts than randomSamples makes
    std::vector<std::uint8_t> counts(s.r.size());
    for (std::size_t i = 0; i < s.r.size(); ++i) counts[i] = s.far[i];
    const SignSamples view = s.view();
    // Every range of w between consecutive breakpoints, probed at its midpoint and beyond the ends: the
    // fewest contradicted samples, and the least contradicted mass among the ranges with that few.
    std::vector<double> breaks;
    for (std::size_t i = 0; i < s.r.size(); ++i)
      if (counts[i] && s.b[i] > 1e-300) breaks.push_back(-s.a[i] / s.b[i]);
    std::sort(breaks.begin(), breaks.end());
    std::vector<double> probes;
    probes.push_back(breaks.empty() ? 0.0 : breaks.front() - 1);
    if (!breaks.empty()) probes.push_back(breaks.back() + 1);
    for (std::size_t k = 0; k + 1 < breaks.size(); ++k)
      if (breaks[k] < breaks[k + 1]) probes.push_back(0.5 * (breaks[k] + breaks[k + 1]));
    int best = std::numeric_limits<int>::max();
    for (double w : probes) best = std::min(best, signViolations(view, counts, w));
    double lightest = std::numeric_limits<double>::infinity(), heaviest = 0;
    for (double w : probes)
      if (signViolations(view, counts, w) == best) {
        lightest = std::min(lightest, contradictedMass(view, counts, w));
        heaviest = std::max(heaviest, contradictedMass(view, counts, w));
      }
    withConflicts += best > 0;
    massDecided += heaviest > lightest * (1 + 1e-6);
    const double w = fewestViolations(view, counts, 0.0);
    ASSERT_EQ(signViolations(view, counts, w), best) << "trial " << trial << " w " << w;
    EXPECT_NEAR(contradictedMass(view, counts, w), lightest, 1e-9 * (1 + lightest)) << "trial " << trial;
    // 0 is one of the best values: it is the answer (the margin is relative, so no finite end but 0 itself
    // keeps 0 out of its range).
    if (signViolations(view, counts, 0.0) == best &&
        contradictedMass(view, counts, 0.0) <= lightest * (1 + 1e-12) &&
        !std::binary_search(breaks.begin(), breaks.end(), 0.0)) {
      EXPECT_EQ(w, 0.0) << "trial " << trial;
    }
  }
  EXPECT_GT(withConflicts, 500);  // the test sees infeasible sets, not only feasible ones
  EXPECT_GT(massDecided, 40);     // and ties in the count that the contradicted mass decides
}

// leastContradicted classifies near samples lazily, yet its choice contradicts as few counting samples as
// fewestViolations with every sample classified, and it confirms only near samples it contradicted.
TEST(SignConstraints, LeastContradictedNeedsOnlyTheNearSamplesItContradicts) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> unit(0, 1);
  std::size_t totalAsked = 0;
  for (int trial = 0; trial < 1000; ++trial) {
    RandomSamples s = randomSamples(rng, 1 + trial % 60, 0.4);
    std::vector<std::uint8_t> confirmed(s.r.size()), counts(s.r.size());
    for (std::size_t i = 0; i < s.r.size(); ++i) {
      if (unit(rng) < 0.1) s.a[i] = -s.a[i];
      confirmed[i] = unit(rng) < 0.5;
      counts[i] = s.far[i] || confirmed[i];
    }
    const SignSamples view = s.view();
    std::vector<int> asked;
    const double w = leastContradicted(
        0.0, view, [&](int i) { return bool(s.far[static_cast<std::size_t>(i)]); },
        [&](int i) {
          asked.push_back(i);
          return bool(confirmed[static_cast<std::size_t>(i)]);
        });
    EXPECT_EQ(signViolations(view, counts, w),
              signViolations(view, counts, fewestViolations(view, counts, 0.0)))
        << "trial " << trial;
    for (int i : asked) EXPECT_FALSE(s.far[static_cast<std::size_t>(i)]) << "trial " << trial;
    totalAsked += asked.size();
  }
  EXPECT_GT(totalAsked, 100u);  // the lazy confirmation is exercised
}
