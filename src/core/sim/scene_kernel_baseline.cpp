// The scene kernels with the build's own universal intrinsics: SSE2 on x86-64, NEON on ARM, the
// scalar code elsewhere. Always built; the fallback when no wider kernel fits the CPU.
#define SCENE_KERNEL_GETTER baselineKernel
#define SCENE_KERNEL_NAME "baseline"
#include "scene_kernel.inl"
