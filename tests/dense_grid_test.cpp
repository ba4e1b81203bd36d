// DenseGrid's range and finiteRange (dense_grid.h): the smallest and largest finite sample, whatever the
// count (the four lanes and the rest) and wherever the extremes and the non-finite samples lie.
#include "cip/volume/dense_grid.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

using namespace cip;

TEST(DenseGrid, FiniteRangeSkipsNaNAndInfinities) {
  constexpr double inf = std::numeric_limits<double>::infinity(),
                   nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(finiteRange(nullptr, 0), std::make_pair(inf, -inf));
  const std::vector<double> none{nan, inf, -inf, nan, nan};
  EXPECT_EQ(finiteRange(none.data(), none.size()), std::make_pair(inf, -inf));
  // Every count from 1 to 13 and every position of the two extremes among finite values in [-1, 1].
  for (std::size_t n = 1; n <= 13; ++n)
    for (std::size_t lo = 0; lo < n; ++lo)
      for (std::size_t hi = 0; hi < n; ++hi) {
        std::vector<double> v(n);
        for (std::size_t i = 0; i < n; ++i)
          v[i] = i % 3 == 0 ? nan : (i % 3 == 1 ? 0.5 - 0.1 * double(i % 5) : (i % 2 ? inf : -inf));
        v[hi] = 7.5;
        if (lo != hi) v[lo] = -3.25;
        const auto [a, b] = finiteRange(v.data(), n);
        double expectLo = inf;
        for (double x : v)
          if (std::abs(x) <= std::numeric_limits<double>::max()) expectLo = std::min(expectLo, x);
        if (lo != hi) {
          EXPECT_EQ(expectLo, -3.25);
        }
        EXPECT_EQ(a, expectLo) << n << " " << lo << " " << hi;
        EXPECT_EQ(b, 7.5) << n << " " << lo << " " << hi;
      }
  DenseGrid g;
  g.allocate({5, 4, 3});
  for (std::size_t i = 0; i < g.values.size(); ++i) g.values[i] = double(i) - 20;
  g.values[0] = nan;
  g.values.back() = inf;
  EXPECT_EQ(g.range(), std::make_pair(-19.0, 38.0));
}
