#pragma once
// The simulated sensor's noise: standard normal deviates that are a pure function of
// (seed, row, column), so any thread may draw any row and the image does not depend on how it
// was split. Each row has four xoshiro128+ streams of its own, seeded by splitmix64 from the seed
// and the row (column c takes the (c / 4)-th output of stream c % 4); the top bits of each
// 32-bit output pick a bin of a tabulated inverse normal CDF and the rest place the deviate
// linearly within it. The table has 4096 equiprobable bins, its outer bins keep the tails'
// conditional means, and it is scaled to unit variance: the deviates end at about 4 sigma,
// which the sensor's rounding and clipping would hide anyway.
//
// Threading: the table is built once (thread-safe static) and only read after.
#include <cstdint>

namespace ecs {
namespace sim {

// out[0, width): the deviates of `row` for `seed`.
void fillNormalRow(uint64_t seed, int row, int width, float* out);

// splitmix64's finaliser: seeds from seeds (the frames' noise seeds, the rows' streams).
uint64_t mixSeed(uint64_t x);

}  // namespace sim
}  // namespace ecs
