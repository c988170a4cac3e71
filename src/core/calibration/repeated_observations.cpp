#include "embedded_calibration_stereo/core/calibration/repeated_observations.h"

#include <algorithm>
#include <cstring>

namespace embedded_calibration_stereo::core {

namespace {

class Fnv1a {
 public:
  template <class T>
  void add(const T& value) {
    unsigned char bytes[sizeof(T)];
    std::memcpy(bytes, &value, sizeof(T));
    for (const unsigned char b : bytes) hash_ = (hash_ ^ b) * 1099511628211ull;
  }
  uint64_t value() const { return hash_; }

 private:
  uint64_t hash_ = 14695981039346656037ull;
};

void addBoards(const std::vector<BoardCorners>& boards, Fnv1a* digest) {
  digest->add(boards.size());
  for (const BoardCorners& b : boards) {
    digest->add(b.board_id);
    digest->add(b.corner_ids.size());
    for (size_t i = 0; i < b.corner_ids.size(); ++i) {
      digest->add(b.corner_ids[i]);
      digest->add(i < b.u.size() ? b.u[i] : 0.0f);
      digest->add(i < b.v.size() ? b.v[i] : 0.0f);
    }
  }
}

}  // namespace

uint64_t contentDigest(const StereoObservation& observation) {
  Fnv1a digest;
  addBoards(observation.left, &digest);
  addBoards(observation.right, &digest);
  digest.add(observation.scene.size());
  for (const SceneMatch& m : observation.scene) {
    digest.add(m.left_u);
    digest.add(m.left_v);
    digest.add(m.right_u);
    digest.add(m.right_v);
  }
  return digest.value();
}

bool RepeatedObservations::repeats(const StereoObservation& observation) {
  const uint64_t digest = contentDigest(observation);
  if (std::find(recent_.begin(), recent_.end(), digest) != recent_.end()) return true;
  recent_.push_back(digest);
  if (recent_.size() > capacity_) recent_.pop_front();
  return false;
}

}  // namespace embedded_calibration_stereo::core
