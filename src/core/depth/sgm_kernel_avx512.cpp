// The census_sgm kernel for x86-64 CPUs with AVX-512 (64 byte lanes: the 64 disparities of the
// head's default range in one register, and a popcount instruction for the census costs). Built
// only on x86-64, with the AVX-512 flags for this file alone (CMakeLists.txt), and called only
// when the CPU has AVX-512 F, BW, VL, DQ, CD, VBMI and BITALG (kernel_choice.h);
// sad_kernel_avx2.cpp explains the defines. VBMI gives the byte permutes OpenCV's lane rotations
// use, BITALG the byte popcount.
#define CV_CPU_DISPATCH_MODE AVX512_ICL
#define CV_AVX 1
#define CV_AVX2 1
#define CV_AVX512_SKX 1
#define CV_AVX_512F 1
#define CV_AVX_512BW 1
#define CV_AVX_512VL 1
#define CV_AVX_512DQ 1
#define CV_AVX_512CD 1
#define CV_AVX_512VBMI 1
#define CV_AVX_512BITALG 1
#include <immintrin.h>
// GCC 12 warns inside its own AVX-512 headers, whose intrinsics start from _mm512_undefined_*().
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif

#define SGM_KERNEL_GETTER avx512Kernel
#define SGM_KERNEL_NAME "avx512"
#include "sgm_kernel.inl"
