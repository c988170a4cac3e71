// The census_sgm kernel for x86-64 CPUs with AVX2 (32 byte lanes instead of SSE2's 16). Built
// only on x86-64, with -mavx2 for this file alone (CMakeLists.txt), and called only when the CPU
// has AVX2; sad_kernel_avx2.cpp explains the defines.
#define CV_CPU_DISPATCH_MODE AVX2
#define CV_AVX 1
#define CV_AVX2 1
#include <immintrin.h>

#define SGM_KERNEL_GETTER avx2Kernel
#define SGM_KERNEL_NAME "avx2"
#include "sgm_kernel.inl"
