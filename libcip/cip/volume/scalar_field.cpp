#include "cip/volume/scalar_field.h"

namespace cip {

void ScalarField::valuesOnLattice(const double* x, const double* y, const double* z,
                                  const std::array<int, 3>& count, const std::array<int, 3>& stride,
                                  double* out) const {
  for (int d = 0; d < count[2]; ++d)
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a)
        out[a * stride[0] + b * stride[1] + d * stride[2]] = value(Vec3(x[a], y[b], z[d]));
}

}  // namespace cip
