#include "cip/patch/sign_constraints.h"

#include <algorithm>
#include <limits>
#include <utility>

#include "cip/core/vector_clones.h"

#if defined(__SSE2__) || defined(__x86_64__)
#include <immintrin.h>
#endif

namespace cip {

namespace {

/// Failure bits of one sample, as CoefficientInterval::slack decides (the fallback and the tail).
std::uint64_t fails(const SignSamples& s, int i, double w) {
  return !(CoefficientInterval::slack(s.r[i] > 0, s.a[i], s.b[i], w) >= 0);
}

/// Failure bits of samples begin to end - 1, all in one word (bit i % 64): the samples a vector loop leaves
/// over, or all of them without SSE2.
std::uint64_t tailBits(const SignSamples& s, int begin, int end, double w) {
  std::uint64_t bits = 0;
  for (int i = begin; i < end; ++i) bits |= fails(s, i, w) << (i % 64);
  return bits;
}

#if defined(__SSE2__)
// CoefficientInterval::slack lane-wise: v = a + w b, negated where r > 0 does not hold (NaN included), minus
// max(kEps |a|, DBL_MIN) (maxpd gives its second operand for a NaN, as the scalar comparison does); a lane
// fails unless the result is >= 0 (NaN fails).
int sweepSse2(const SignSamples& s, double w, std::uint64_t* failing) {
  const __m128d ww = _mm_set1_pd(w), zero = _mm_setzero_pd(), signBit = _mm_set1_pd(-0.0),
                eps = _mm_set1_pd(CoefficientInterval::kEps),
                tiny = _mm_set1_pd(std::numeric_limits<double>::min());
  int failures = 0;
  for (int base = 0; base < s.count; base += 64) {
    const int end = std::min(s.count, base + 64);
    std::uint64_t bits = 0;
    int i = base;
    for (; i + 2 <= end; i += 2) {
      const __m128d r = _mm_loadu_pd(s.r + i), a = _mm_loadu_pd(s.a + i), b = _mm_loadu_pd(s.b + i);
      const __m128d v = _mm_add_pd(a, _mm_mul_pd(ww, b));
      const __m128d flip = _mm_andnot_pd(_mm_cmpgt_pd(r, zero), signBit);
      const __m128d needed = _mm_max_pd(_mm_mul_pd(eps, _mm_andnot_pd(signBit, a)), tiny);
      const __m128d slack = _mm_sub_pd(_mm_xor_pd(v, flip), needed);
      const int pass = _mm_movemask_pd(_mm_cmpge_pd(slack, zero));
      bits |= static_cast<std::uint64_t>(pass ^ 3) << (i - base);
    }
    bits |= tailBits(s, i, end, w);
    failing[base / 64] = bits;
    failures += __builtin_popcountll(bits);
  }
  return failures;
}
#endif

#if defined(CIP_HAS_AVX2_KERNELS)
// As sweepSse2, four lanes at a time.
CIP_AVX2_KERNEL int sweepAvx2(const SignSamples& s, double w, std::uint64_t* failing) {
  const __m256d ww = _mm256_set1_pd(w), zero = _mm256_setzero_pd(), signBit = _mm256_set1_pd(-0.0),
                eps = _mm256_set1_pd(CoefficientInterval::kEps),
                tiny = _mm256_set1_pd(std::numeric_limits<double>::min());
  int failures = 0;
  for (int base = 0; base < s.count; base += 64) {
    const int end = std::min(s.count, base + 64);
    std::uint64_t bits = 0;
    int i = base;
    for (; i + 4 <= end; i += 4) {
      const __m256d r = _mm256_loadu_pd(s.r + i), a = _mm256_loadu_pd(s.a + i), b = _mm256_loadu_pd(s.b + i);
      const __m256d v = _mm256_add_pd(a, _mm256_mul_pd(ww, b));
      const __m256d flip = _mm256_andnot_pd(_mm256_cmp_pd(r, zero, _CMP_GT_OQ), signBit);
      const __m256d needed = _mm256_max_pd(_mm256_mul_pd(eps, _mm256_andnot_pd(signBit, a)), tiny);
      const __m256d slack = _mm256_sub_pd(_mm256_xor_pd(v, flip), needed);
      const int pass = _mm256_movemask_pd(_mm256_cmp_pd(slack, zero, _CMP_GE_OQ));
      bits |= static_cast<std::uint64_t>(pass ^ 15) << (i - base);
    }
    bits |= tailBits(s, i, end, w);
    failing[base / 64] = bits;
    failures += __builtin_popcountll(bits);
  }
  return failures;
}
#endif

}  // namespace

int slackSweep(const SignSamples& s, double w, std::uint64_t* failing) {
#if defined(CIP_HAS_AVX2_KERNELS)
  if (hasAvx2()) return sweepAvx2(s, w, failing);
#endif
#if defined(__SSE2__)
  return sweepSse2(s, w, failing);
#else
  int failures = 0;
  for (int base = 0; base < s.count; base += 64) {
    const std::uint64_t bits = tailBits(s, base, std::min(s.count, base + 64), w);
    failing[base / 64] = bits;
    failures += __builtin_popcountll(bits);
  }
  return failures;
#endif
}

int signViolations(const SignSamples& s, const std::vector<std::uint8_t>& counts, double w) {
  int violations = 0;
  for (int i = 0; i < s.count; ++i) {
    violations += counts[static_cast<std::size_t>(i)] && contradicts(s, i, w);
  }
  return violations;
}

double fewestViolations(const SignSamples& s, const std::vector<std::uint8_t>& counts, double preferred) {
  constexpr double kInf = CoefficientInterval::kInf, kEps = CoefficientInterval::kEps;
  // A breakpoint with the change in the count (and in the summed |r| of the contradicted samples) when w
  // passes it upwards; `violations` (`mass`) is the count (sum) below all of them.
  struct Step {
    double at;
    int count;
    double mass;
    bool operator<(const Step& o) const { return at < o.at; }
  };
  std::vector<Step> steps;
  int violations = 0;
  double mass = 0;
  for (int i = 0; i < s.count; ++i) {
    if (!counts[static_cast<std::size_t>(i)]) continue;
    const bool positive = s.r[i] > 0;
    const double weight = std::abs(s.r[i]);
    if (!(s.b[i] > 1e-300)) {
      if ((s.a[i] > 0) != positive) {
        ++violations;
        mass += weight;
      }
      continue;
    }
    const double t = -s.a[i] / s.b[i];
    if (!std::isfinite(t)) continue;
    if (positive) {  // needs w > t
      ++violations;
      mass += weight;
      steps.push_back({t, -1, -weight});
    } else {  // needs w < t
      steps.push_back({t, +1, weight});
    }
  }
  std::sort(steps.begin(), steps.end());
  double total = mass;
  for (const Step& step : steps) total += std::max(step.mass, 0.0);
  const double tolerance = 1e-12 * total;  // the sums below are running ones
  if (!std::isfinite(preferred)) preferred = 0;
  double best = preferred;
  int bestCount = std::numeric_limits<int>::max();
  double bestMass = kInf, bestDistance = kInf;
  auto consider = [&](double lo, double hi, int count, double weight) {
    const double a = std::isfinite(lo) ? lo + kEps * std::abs(lo) : lo;
    const double b = std::isfinite(hi) ? hi - kEps * std::abs(hi) : hi;
    const double w = a <= b ? std::clamp(preferred, a, b) : 0.5 * (lo + hi);  // a > b: both ends finite
    const double distance = std::abs(w - preferred);
    // Fewer contradicted samples first; among as many, the least reference value contradicted (up to the
    // rounding of the running sums); then the nearest.
    const bool fewer = count < bestCount;
    const bool lighter = count == bestCount && weight < bestMass - tolerance;
    const bool asLight = count == bestCount && !lighter && !(weight > bestMass + tolerance);
    if (fewer || lighter || (asLight && distance < bestDistance)) {
      best = w;
      bestCount = count;
      bestMass = weight;
      bestDistance = distance;
    }
  };
  double lo = -kInf;
  for (std::size_t k = 0; k < steps.size();) {
    consider(lo, steps[k].at, violations, mass);
    lo = steps[k].at;
    for (; k < steps.size() && steps[k].at == lo; ++k) {
      violations += steps[k].count;
      mass += steps[k].mass;
    }
  }
  consider(lo, kInf, violations, mass);
  return best;
}

}  // namespace cip
