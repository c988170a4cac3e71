#pragma once
// Calibration files of camera_info_manager URLs, written atomically.
//
// URL resolution follows camera_info_manager: an empty URL means
// file://${ROS_HOME}/camera_info/${NAME}.yaml; ${NAME} and ${ROS_HOME} (default ~/.ros) are
// substituted in one pass; file:// takes an absolute path and package://PKG/PATH a path inside
// a ROS package. Other schemes are not writable files and are rejected.
//
// writeCalibrationFileAtomic() writes the camera_calibration_parsers format (YAML, or INI for a
// .ini name) to a temporary file in the target's directory, fsyncs it, renames it over the
// target and fsyncs the directory, so a crash at any point leaves either the old or the new
// complete file, never a truncated one.
// All functions are thread-safe (no shared state).
//
// CalibrationPairStore (below) keeps the two files of a stereo pair consistent with each other.
#include <sensor_msgs/CameraInfo.h>

#include <functional>
#include <set>
#include <string>
#include <vector>

namespace embedded_calibration_stereo {

// Resolves `url` for camera `camera_name` to a local file path. Returns false and the reason
// in *error for an unsupported scheme, an unknown package or an empty path.
bool resolveCalibrationUrl(const std::string& url, const std::string& camera_name,
                           std::string* path, std::string* error);

// Writes `info` for `camera_name` to `path` atomically, creating missing parent directories.
// Returns false and the reason (with the OS error) in *error; the previous file, if any, is
// then unchanged and no temporary file is left behind.
bool writeCalibrationFileAtomic(const std::string& path, const std::string& camera_name,
                                const sensor_msgs::CameraInfo& info, std::string* error);

// Reads a calibration file. Returns false and the reason in *error when it is missing or
// cannot be parsed.
bool readCalibrationFile(const std::string& path, std::string* camera_name,
                         sensor_msgs::CameraInfo* info, std::string* error);

// What readCalibrationFileIfPresent found.
enum class CalibrationFileState { kMissing, kLoaded, kBroken };
// Like readCalibrationFile, telling a missing file (or a symbolic link to nothing) apart from
// one that exists but cannot be read or parsed (kBroken, with the reason in *error).
CalibrationFileState readCalibrationFileIfPresent(const std::string& path, sensor_msgs::CameraInfo* info,
                                                  std::string* error);

// The two calibration files of a stereo head, changed together: after a crash at any moment
// both show the old calibration or both the new one.
//
// Layout (names for URL files stereo_left.yaml and stereo_right.yaml):
//   <dir of the left file>/.stereo_left+stereo_right.generations/
//       g000007/left.yaml, g000007/right.yaml    one calibration pair per generation
//       g000008/left.yaml, g000008/right.yaml
//       current -> g000008                       symbolic link
//   <left URL file>  -> .stereo_left+stereo_right.generations/current/left.yaml
//   <right URL file> -> (the same)/current/right.yaml    (absolute when in another folder)
// A reader that opens a URL file (our driver, camera_info_manager, a user) reads the current
// generation. commit() writes a complete new generation, then replaces `current` with one
// rename(): that rename is the single atomic step that moves both cameras to the new pair.
// The URL files themselves are turned into the links once (the first commit), with a
// generation holding exact copies of what they showed, so that they show the same content at
// every moment of that conversion too. Generation files take each URL file's extension
// (.yaml, or .ini for the INI format).
// A generation the calibration health verified GOOD carries a file `verified` (markVerified()):
// the calibration a rollback or a rejected file falls back to, across restarts.
// commit() keeps the new generation, the one it replaces, the newest valid generation before
// them when neither of those is valid (the previous calibration the driver falls back to) and
// the newest verified valid one, and deletes older ones.
//
// Test hook, inert unless set: with the environment variable ECS_TEST_CRASH_COMMIT_AT=k the
// process kills itself (SIGKILL) right after the k-th durable step of a commit (steps 1-5
// convert the URL files, whether or not there is anything to convert; 6 and 7 write the new
// generation's files, 8 replaces `current`, 9 deletes old generations), so that tests can
// check the files after a crash at each step.
//
// Threading: no internal state besides the paths; the caller serialises commits.
class CalibrationPairStore {
 public:
  struct Generation {
    unsigned number = 0;
    std::string directory, left_file, right_file;
    std::string verified_file;  // present when the generation was verified GOOD
    bool verified = false;      // verified_file exists
  };

  CalibrationPairStore(std::string left_path, std::string right_path, std::string left_camera_name,
                       std::string right_camera_name);

  const std::string& leftPath() const { return left_path_; }
  const std::string& rightPath() const { return right_path_; }
  const std::string& directory() const { return directory_; }

  // Every generation on disk, newest first, whatever its content (may be incomplete).
  std::vector<Generation> generations() const;
  // The generation `current` points to; 0 when there is none.
  unsigned currentGeneration() const;
  // The generation both URL files show: currentGeneration() when both are our links, else 0.
  unsigned linkedGeneration() const;
  // Marks generation `number` verified GOOD (its `verified` file, written atomically, holds
  // `note`). Throws std::runtime_error naming the path and the system's reason.
  void markVerified(unsigned number, const std::string& note) const;

  // Makes (left, right) the calibration of both URL files in one atomic step and returns the
  // new generation's number. `is_valid` tells which older generations can serve as a fallback.
  // Throws std::runtime_error naming the path and the system's reason; the URL files then still
  // show the calibration they showed before.
  unsigned commit(const sensor_msgs::CameraInfo& left, const sensor_msgs::CameraInfo& right,
                  const std::function<bool(const Generation&)>& is_valid);

 private:
  Generation generation(unsigned number) const;
  std::string linkTarget(bool left) const;  // what a URL file that is ours points to
  bool isOurLink(bool left) const;
  void makeCurrent(unsigned number) const;
  void linkUrlFile(bool left) const;
  // Deletes the generations a commit of `newest` does not keep (see above) besides `keep`, and
  // leftovers of crashed commits (temporary links).
  void prune(unsigned newest, std::set<unsigned> keep, const std::function<bool(const Generation&)>& is_valid) const;

  std::string left_path_, right_path_;
  std::string left_camera_name_, right_camera_name_;
  std::string directory_;
  std::string left_extension_, right_extension_;
};

}  // namespace embedded_calibration_stereo
