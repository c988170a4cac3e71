// The sad kernel for x86-64 CPUs with AVX2: 16 int16 lanes instead of SSE2's 8. Built only on
// x86-64, with -mavx2 for this file alone (CMakeLists.txt), and called only when
// cv::checkHardwareSupport(CV_CPU_AVX2) says the CPU has it (sad_matcher.cpp).
// CV_AVX2 makes OpenCV's headers add their 256-bit universal intrinsics (and map cv::v_int16 and
// vx_* to them); CV_CPU_DISPATCH_MODE puts them in a namespace of their own (hal_AVX2), apart
// from the baseline ones that other files instantiate.
#define CV_CPU_DISPATCH_MODE AVX2
#define CV_AVX 1
#define CV_AVX2 1
#include <immintrin.h>  // what OpenCV's own dispatch would include for CV_AVX2

#define SAD_KERNEL_GETTER avx2Kernel
#define SAD_KERNEL_NAME "avx2"
#include "sad_kernel.inl"
