/* What every C file of the moegs CPU library shares: OpenMP when the compiler has it, and the
 * attribute that exports an entry point (the library is built with -fvisibility=hidden). */
#ifndef MOEGS_API_H
#define MOEGS_API_H

#ifdef _OPENMP
#include <omp.h>
#endif

#if defined(_WIN32)
#define MOEGS_API __declspec(dllexport)
#else
#define MOEGS_API __attribute__((visibility("default")))
#endif

/* Marks a failed allocation from inside an OpenMP parallel region. */
static inline void flag_error(int *err) {
#pragma omp atomic write
    *err = 1;
}

#endif
