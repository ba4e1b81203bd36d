/// @file vector_clones.h
/// @brief CIP_VECTOR_CLONES: compile a hot loop twice, for AVX2 and for the baseline, chosen at run time.
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
