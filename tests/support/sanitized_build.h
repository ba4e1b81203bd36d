// Whether this test program was built with AddressSanitizer (the CIP_SANITIZE build that scripts/test.sh runs
// after the Release one), where the library runs several times slower. Suites whose large cases check numbers
// rather than memory use keep those cases to the Release run; the sanitizer run still takes every code path
// on the smaller cases.
#pragma once

#include "cip/core/vector_clones.h"  // CIP_ADDRESS_SANITIZER: GCC's and Clang's ways of telling

namespace cip::test {

// The two OpenVDB suites compile their own sources without instrumentation in that build
// (tests/CMakeLists.txt) and are told so by CIP_LEAK_SANITIZER.
#if defined(CIP_ADDRESS_SANITIZER) || defined(CIP_LEAK_SANITIZER)
inline constexpr bool kSanitizedBuild = true;
#else
inline constexpr bool kSanitizedBuild = false;
#endif

}  // namespace cip::test
