/// @file vector_clones.h
/// @brief CIP_VECTOR_CLONES: compile a hot loop twice, for AVX2 and for the baseline, chosen at run time; and
/// CIP_AVX2_KERNEL / hasAvx2() for kernels written with AVX2 intrinsics beside a baseline version.
///
/// Function multi-versioning (GCC and Clang on x86-64 with ifunc support): the AVX2 clone runs the same
/// operations four doubles at a time. Fused multiply-add is not enabled, so both clones give bit-identical
/// results. Used on loops written to vectorise (independent outputs, contiguous arrays). Off under
/// AddressSanitizer (GCC defines __SANITIZE_ADDRESS__, Clang reports the feature), which does not support
/// the resolver.
#pragma once

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

/// CIP_AVX2_KERNEL marks a function written with AVX2 intrinsics; it is defined, with CIP_HAS_AVX2_KERNELS,
/// where the compiler takes the target attribute on x86-64 (also under the sanitizers, unlike the clones).
/// Such a kernel is called only where hasAvx2(), beside a baseline version of the same arithmetic (no fused
/// multiply-add, so both give the same bits).
#if defined(__x86_64__) && defined(__has_attribute)
#if __has_attribute(target)
#define CIP_HAS_AVX2_KERNELS 1
#define CIP_AVX2_KERNEL __attribute__((target("avx2")))
#endif
#endif

#include <atomic>

namespace cip {

namespace detail {
inline std::atomic<bool>& avx2KernelsOff() {
  static std::atomic<bool> off{false};
  return off;
}
}  // namespace detail

/// Whether the AVX2 kernels run: this processor has AVX2 (asked once) and setAvx2Kernels(false) did not turn
/// them off.
inline bool hasAvx2() {
#if defined(CIP_HAS_AVX2_KERNELS)
  static const bool avx2 = __builtin_cpu_supports("avx2");
  return avx2 && !detail::avx2KernelsOff().load(std::memory_order_relaxed);
#else
  return false;
#endif
}

/// Turns the AVX2 kernels (CIP_AVX2_KERNEL) off or back on for the whole process, so that their baseline
/// versions run: what a processor without AVX2 computes, for tests that compare the two bit for bit. The
/// CIP_VECTOR_CLONES loops are chosen when the program loads and are not affected. Call it between builds,
/// not during one.
inline void setAvx2Kernels(bool on) {
  detail::avx2KernelsOff().store(!on, std::memory_order_relaxed);
}

}  // namespace cip
