// The scene kernels for x86-64 CPUs with AVX2 and FMA: 8 float lanes with hardware gathers and
// fused multiply-adds instead of SSE2's 4. Built only on x86-64, with -mavx2 -mfma for this file
// alone (CMakeLists.txt), and called only when the CPU has both (scene_kernel.cpp).
// CV_CPU_DISPATCH_MODE puts OpenCV's 256-bit universal intrinsics in a namespace of their own
// (hal_AVX2), apart from the baseline ones that other files instantiate.
#define CV_CPU_DISPATCH_MODE AVX2
#define CV_AVX 1
#define CV_AVX2 1
#define CV_FMA3 1
#include <immintrin.h>  // what OpenCV's own dispatch would include for CV_AVX2

#define SCENE_KERNEL_GETTER avx2Kernel
#define SCENE_KERNEL_NAME "avx2"
#include "scene_kernel.inl"
