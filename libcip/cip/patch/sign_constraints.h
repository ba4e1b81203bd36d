/// @file sign_constraints.h
/// @brief One patch coefficient w fitted under sign constraints, checked lazily (used by the face and cell
/// fits, face_fit.h and cell_fit.h).
///
/// At sample i the patch is a_i + w b_i (b_i >= 0) and should have the sign of the reference r_i. Every
/// sample that lies away from the reference surface constrains w to a half-line; the coefficient is the
/// fitted value clamped into the intersection, a relative margin away from its ends. Deciding whether a
/// sample lies away from the surface needs the reference gradient, and intersecting needs a division per
/// sample, yet a sample that the clamped value already satisfies with the margin changes nothing. So the
/// samples are checked against the current value (a multiply-add each) and only those it fails are examined
/// and, if they count, added; the value is clamped again and the check repeated until no sample is added.
/// The result is the clamp into the interval of all counting samples, because a value inside the margined
/// interval of a subset that satisfies every other sample with the margin lies inside the margined interval
/// of all of them, where clamping gives the same value.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

namespace cip {

/// Interval of a coefficient w with sign(s) * (a + w b) > 0 for all added constraints (b >= 0).
struct CoefficientInterval {
  static constexpr double kInf = std::numeric_limits<double>::infinity();
  /// Relative margin of clamp: at the end t = -a / b of a constraint, a + w b >= kEps |a| needs
  /// w >= t + kEps |t|, so the zero set stays away from the sample that defines an end. That sample lies away
  /// from the reference surface; with a thin margin (0.05) the patch's zero set could pass just beside it
  /// and, between samples, more than half a voxel from the surface (headsq at 1150: 2 wrong-sign cells on the
  /// 8^3 lattice with 0.05, 0 with 0.4; docs/method.md has the sweep).
  static constexpr double kEps = 0.4;
  double lo = -kInf, hi = kInf;
  bool empty = false;

  void add(bool positive, double a, double b) {
    if (!(b > 1e-300)) {
      empty |= (a > 0) != positive;
      return;
    }
    const double bound = -a / b;
    if (positive)
      lo = std::max(lo, bound);
    else
      hi = std::min(hi, bound);
  }
  bool feasible() const { return !empty && lo < hi; }
  /// `w` moved into the interval, kEps relative away from each end (the midpoint when that is empty).
  double clamp(double w) const {
    const double a = std::isfinite(lo) ? lo + kEps * std::abs(lo) : lo;
    const double b = std::isfinite(hi) ? hi - kEps * std::abs(hi) : hi;
    if (!(a <= b)) return 0.5 * (lo + hi);
    return std::clamp(w, a, b);
  }
  /// How far w meets the constraint (positive, a, b) with the margin of clamp: it does iff the slack is >= 0
  /// (s > 0 and s >= kEps |a| for s = sign * (a + w b); the smallest normal double stands for "> 0"). NaN
  /// does not meet it.
  static double slack(bool positive, double a, double b, double w) {
    const double v = a + w * b;
    const double s = positive ? v : -v;
    const double needed = kEps * std::abs(a);
    return s - (needed > std::numeric_limits<double>::min() ? needed : std::numeric_limits<double>::min());
  }
};

/// Result of solveSignConstraints.
struct SignedCoefficient {
  double value = 0;  ///< the clamped coefficient (the fitted one when infeasible)
  bool feasible = true;
};

/// Samples of one fit in structure-of-arrays form: reference value minus isovalue r, the patch without the
/// coefficient a, the coefficient's basis b.
struct SignSamples {
  const double* r;
  const double* a;
  const double* b;
  int count;
};

/// The samples that w fails: sets bit i % 64 of failing[i / 64] for every sample i whose
/// CoefficientInterval::slack(r_i > 0, a_i, b_i, w) is negative (or NaN), clears the other bits of the
/// (s.count + 63) / 64 words, and returns how many bits are set. The hot loop of solveSignConstraints:
/// two or four samples at a time (SSE2, or AVX2 where the processor has it; the same arithmetic, no fused
/// multiply-add), their failures taken as bits from the comparison, so that the samples that pass cost no
/// branch.
int slackSweep(const SignSamples& s, double w, std::uint64_t* failing);

/// Clamps fitted coefficients into the interval of the samples that count, keeping what it learnt between
/// calls (see solve).
class SignConstraintSolver {
 public:
  /// Forgets every sample and the interval.
  void reset() {
    state_.clear();
    interval_ = CoefficientInterval{};
    confirmedNear_ = 0;
  }
  /// Samples found near the surface after the value of some step gave them the wrong sign (confirmFar false):
  /// every sample that the result gives the wrong sign is among them.
  int confirmedNear() const { return confirmedNear_; }

  /// Clamps the fitted coefficient `w` into the interval of the samples that count:
  ///  - `far(i)`: sample i lies farther than the margin from the reference surface (a first-order estimate);
  ///    it counts;
  ///  - `confirmFar(i)`: asked once for a sample that is not far but to which the clamped value gives the
  ///    wrong sign (a + w b against r, no margin); if true, the sample counts from then on.
  /// Both are called only for samples that the current value fails, so they may be expensive. The samples of
  /// an earlier call since reset() must be the first ones of `s`: what is known of them is kept (the
  /// samples that count and the interval, those found near), so a call with more samples asks the callbacks
  /// only about new samples and about earlier ones that the new value fails and that were never asked. Each
  /// callback is asked at most once per sample between resets. When every sample counts, the result is that
  /// of one call with all the samples: the clamp into the interval of all of them.
  template <class Far, class ConfirmFar>
  SignedCoefficient solve(double w, const SignSamples& s, Far&& far, ConfirmFar&& confirmFar) {
    const std::size_t words = (static_cast<std::size_t>(s.count) + 63) / 64;
    state_.resize(static_cast<std::size_t>(s.count), kUnknown);
    failing_.resize(words);
    if (!std::isfinite(w)) w = 0;
    double value = interval_.feasible() ? interval_.clamp(w) : w;
    for (;;) {
      // The sweep over all samples is branch-free; failures are rare and examined below, in index order.
      if (slackSweep(s, value, failing_.data()) == 0) break;
      bool added = false;
      for (std::size_t word = 0; word < words; ++word)
        for (std::uint64_t bits = failing_[word]; bits; bits &= bits - 1) {
          const int i = static_cast<int>(64 * word) + __builtin_ctzll(bits);
          const auto k = static_cast<std::size_t>(i);
          if (state_[k] == kCounting || state_[k] == kConfirmedNear) continue;
          if (state_[k] == kUnknown) state_[k] = far(i) ? kCounting : kNear;
          if (state_[k] == kNear) {
            const double v = s.a[i] + value * s.b[i];
            if ((v > 0) == (s.r[i] > 0) || v == 0) continue;
            state_[k] = confirmFar(i) ? kCounting : kConfirmedNear;
            confirmedNear_ += state_[k] == kConfirmedNear;
          }
          if (state_[k] != kCounting) continue;
          interval_.add(s.r[i] > 0, s.a[i], s.b[i]);
          added = true;
        }
      if (!added || !interval_.feasible()) break;
      value = interval_.clamp(w);
    }
    SignedCoefficient out;
    out.feasible = interval_.feasible();
    out.value = out.feasible ? interval_.clamp(w) : w;
    if (!std::isfinite(out.value)) out.value = 0;
    return out;
  }

 private:
  // Per sample: unclassified, counting (added), near, near and confirmed near.
  enum : std::uint8_t { kUnknown, kCounting, kNear, kConfirmedNear };
  std::vector<std::uint8_t> state_;
  std::vector<std::uint64_t> failing_;
  CoefficientInterval interval_;
  int confirmedNear_ = 0;
};

/// SignConstraintSolver::solve on its own: the samples `s` alone.
template <class Far, class ConfirmFar>
SignedCoefficient solveSignConstraints(double w, const SignSamples& s, Far&& far, ConfirmFar&& confirmFar) {
  thread_local SignConstraintSolver solver;
  solver.reset();
  return solver.solve(w, s, std::forward<Far>(far), std::forward<ConfirmFar>(confirmFar));
}

/// Whether coefficient w gives sample i the wrong sign (a + w b against r; zero counts as wrong).
inline bool contradicts(const SignSamples& s, int i, double w) {
  const double v = s.a[i] + w * s.b[i];
  return !(s.r[i] > 0 ? v > 0 : v < 0);
}

/// Number of counting samples to which coefficient w gives the wrong sign (contradicts). `counts[i]` says
/// whether sample i counts.
int signViolations(const SignSamples& s, const std::vector<std::uint8_t>& counts, double w);

/// For samples without a common coefficient: a coefficient that the fewest counting samples contradict;
/// among ranges of w with as few, one whose contradicted samples have the least summed |r| (the reference's
/// own measure of how deep they lie on their side: a noise-level dip of the reference below the isovalue
/// weighs less than a sample well inside, where counting alone ties); among those, the value nearest to
/// `preferred`. The value is kept CoefficientInterval::kEps (relative) inside the finite ends of its range of
/// w (the range's midpoint when it is narrower than that). `counts[i]` says whether sample i counts. Every
/// counting sample with b > 0 is wrong on one side of its breakpoint -a / b, so the count and the sum are
/// step functions of w and the ranges between consecutive breakpoints are all there is to compare.
double fewestViolations(const SignSamples& s, const std::vector<std::uint8_t>& counts, double preferred);

/// fewestViolations for samples classified as solveSignConstraints does: `far(i)` is asked for every sample;
/// `confirmFar(i)` only for a sample that is not far but that the chosen value contradicts, and if it is
/// true the sample counts and the choice is repeated. The result contradicts no more counting samples than
/// with every sample classified: the samples never confirmed have the right sign at it, and no value
/// contradicts fewer of those known to count.
template <class Far, class ConfirmFar>
double leastContradicted(double preferred, const SignSamples& s, Far&& far, ConfirmFar&& confirmFar) {
  std::vector<std::uint8_t> counts(static_cast<std::size_t>(s.count)), checked;
  for (int i = 0; i < s.count; ++i) counts[static_cast<std::size_t>(i)] = far(i);
  checked = counts;
  for (;;) {
    const double w = fewestViolations(s, counts, preferred);
    bool added = false;
    for (int i = 0; i < s.count; ++i) {
      const auto k = static_cast<std::size_t>(i);
      if (checked[k] || !contradicts(s, i, w)) continue;
      checked[k] = 1;
      if (confirmFar(i)) {
        counts[k] = 1;
        added = true;
      }
    }
    if (!added) return w;
  }
}

}  // namespace cip
