#include "cip/sign_constraints.h"

namespace cip {

// Function multi-versioning (GCC and Clang on x86-64 with ifunc support): the AVX2 clone runs the same
// operations four doubles at a time. FMA is not enabled, so results are bit-identical to the default clone.
// Not under AddressSanitizer (GCC defines __SANITIZE_ADDRESS__, Clang reports the feature).
#if defined(__has_feature)
#if __has_feature(address_sanitizer)
#define CIP_ADDRESS_SANITIZER 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__)
#define CIP_ADDRESS_SANITIZER 1
#endif
#if defined(__x86_64__) && defined(__has_attribute) && !defined(CIP_ADDRESS_SANITIZER)
#if __has_attribute(target_clones)
#define CIP_VECTOR_CLONES __attribute__((target_clones("avx2", "default")))
#endif
#endif
#ifndef CIP_VECTOR_CLONES
#define CIP_VECTOR_CLONES
#endif

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

}  // namespace cip
