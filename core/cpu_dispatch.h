// DROPFIT_CPU_CLONES: a hot numeric function compiled twice, for x86-64-v3
// (AVX2, FMA) and for the baseline x86-64, with the copy chosen when the
// program loads by what the CPU runs (GCC's target_clones, an ifunc); one
// binary, no -march at build time, the same on every Debian 12 machine.
// `flatten` inlines everything the function calls into each copy, so the
// integrator's steps themselves take the wider instructions.
//
// The copies differ in rounding only (FMA contracts a*b+c): results agree
// to the last few bits, not bit for bit, across CPUs. Elsewhere (clang,
// other architectures) it expands to nothing, and so it does in a sanitizer
// build (DROPFIT_NO_CPU_CLONES): the ifunc resolver runs while the program
// is relocated, before a sanitizer's runtime is set up, and an instrumented
// resolver crashes there (ThreadSanitizer does, before main).
#pragma once

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && \
    !defined(DROPFIT_NO_CPU_CLONES)
#define DROPFIT_CPU_CLONES __attribute__((target_clones("arch=x86-64-v3", "default"), flatten))
#else
#define DROPFIT_CPU_CLONES
#endif
