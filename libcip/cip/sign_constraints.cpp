#include "cip/sign_constraints.h"

#include <algorithm>
#include <utility>

#include "cip/vector_clones.h"

namespace cip {

CIP_VECTOR_CLONES int slackSweep(const SignSamples& s, double w, double* slack) {
  // Failures are counted in doubles (which keeps the loop vectorisable) in four sums, so that the additions
  // do not wait on one another.
  auto failure = [&](int i) {
    slack[i] = CoefficientInterval::slack(s.r[i] > 0, s.a[i], s.b[i], w);
    return slack[i] >= 0 ? 0.0 : 1.0;
  };
  double failures[4] = {0, 0, 0, 0};
  int i = 0;
  for (; i + 4 <= s.count; i += 4)
    for (int j = 0; j < 4; ++j) failures[j] += failure(i + j);
  double total = failures[0] + failures[1] + failures[2] + failures[3];
  for (; i < s.count; ++i) total += failure(i);
  return static_cast<int>(total);
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
  // Breakpoints with the change in the count when w passes them upwards; `violations` is the count below all.
  std::vector<std::pair<double, int>> steps;
  int violations = 0;
  for (int i = 0; i < s.count; ++i) {
    if (!counts[static_cast<std::size_t>(i)]) continue;
    const bool positive = s.r[i] > 0;
    if (!(s.b[i] > 1e-300)) {
      violations += (s.a[i] > 0) != positive;
      continue;
    }
    const double t = -s.a[i] / s.b[i];
    if (!std::isfinite(t)) continue;
    if (positive) {  // needs w > t
      ++violations;
      steps.emplace_back(t, -1);
    } else {  // needs w < t
      steps.emplace_back(t, +1);
    }
  }
  std::sort(steps.begin(), steps.end());
  if (!std::isfinite(preferred)) preferred = 0;
  double best = preferred;
  int bestCount = std::numeric_limits<int>::max();
  double bestDistance = kInf;
  auto consider = [&](double lo, double hi, int count) {
    const double a = std::isfinite(lo) ? lo + kEps * std::abs(lo) : lo;
    const double b = std::isfinite(hi) ? hi - kEps * std::abs(hi) : hi;
    const double w = a <= b ? std::clamp(preferred, a, b) : 0.5 * (lo + hi);  // a > b: both ends finite
    const double distance = std::abs(w - preferred);
    if (count < bestCount || (count == bestCount && distance < bestDistance)) {
      best = w;
      bestCount = count;
      bestDistance = distance;
    }
  };
  double lo = -kInf;
  for (std::size_t k = 0; k < steps.size();) {
    consider(lo, steps[k].first, violations);
    lo = steps[k].first;
    for (; k < steps.size() && steps[k].first == lo; ++k) violations += steps[k].second;
  }
  consider(lo, kInf, violations);
  return best;
}

}  // namespace cip
