// The census_sgm kernel with the build's own universal intrinsics (SSE2 on x86-64, NEON on ARM).
// Always built; the fallback when no wider kernel fits the CPU.
#define SGM_KERNEL_GETTER baselineKernel
#define SGM_KERNEL_NAME "baseline"
#include "sgm_kernel.inl"
