/// @file bisection.h
/// @brief Bisection of a bracketed sign change, the small root finder shared by the builders and the
/// measures.
#pragma once

namespace cip {

/// Halves [lo, hi] `iterations` times keeping a sign change of f inside (f(lo) has the sign of `fLo`, f(hi)
/// the other sign, with "positive" meaning > 0 as everywhere in cip) and returns the final bracket's
/// midpoint.
template <class F>
double bisectSignChange(F&& f, double lo, double hi, double fLo, int iterations = 60) {
  for (int it = 0; it < iterations; ++it) {
    double mid = 0.5 * (lo + hi), fm = f(mid);
    if ((fm > 0) == (fLo > 0)) {
      lo = mid;
      fLo = fm;
    } else {
      hi = mid;
    }
  }
  return 0.5 * (lo + hi);
}

}  // namespace cip
