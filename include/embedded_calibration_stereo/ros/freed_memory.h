#pragma once
// Hands the memory freed by a burst's work back to the system.
//
// The head's heavy work comes in bursts: a light burst tracked as a whole, the tracker taught, a
// device image learned, a calibration solved; each allocates tens of MB for a second or two and
// frees them. glibc's allocator keeps what a thread frees in that thread's arena for later use,
// and it returns only the end of an arena to the system: the head's manager, whose workers and
// callback threads each have one, stays at the sum of every arena's high-water mark
// (docs/figures.md measures it). Each worker calls releaseFreedMemory() when its work is done.
//
// Threads: any thread. glibc locks each arena while it trims it, and returning 90 MB takes about
// 25 ms (a thread allocating from that arena meanwhile waits): once per burst or solve, never per
// frame.
namespace embedded_calibration_stereo {

// Returns the free pages of every arena to the system (glibc's malloc_trim). True when some
// memory was returned; false when there was none, or on a C library without malloc_trim.
bool releaseFreedMemory();

}  // namespace embedded_calibration_stereo
