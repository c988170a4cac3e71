#pragma once
// Error thrown by every core loader and validator. The message always names the offending
// parameter (as a dotted path such as "cameras.left.fx") and the problem.
#include <stdexcept>
#include <string>

namespace embedded_calibration_stereo::core {

// What a validator found: the parameter and what is wrong with it, kept apart so that a caller
// can refuse the parameter by name without reading the sentence (both empty: nothing wrong).
struct ConfigProblem {
  std::string parameter;
  std::string problem;
  bool ok() const { return parameter.empty() && problem.empty(); }
  // "parameter problem", the validators' one-line form; empty when ok().
  std::string text() const { return ok() ? std::string() : parameter + " " + problem; }
};

class ConfigError : public std::runtime_error {
 public:
  ConfigError(const std::string& parameter, const std::string& problem)
      : std::runtime_error(parameter + ": " + problem), parameter_(parameter) {}
  const std::string& parameter() const { return parameter_; }

 private:
  std::string parameter_;
};

// Throws ConfigError(parameter, problem) unless the problem is ok().
inline void throwIfProblem(const ConfigProblem& p) {
  if (!p.ok()) throw ConfigError(p.parameter, p.problem);
}

}  // namespace embedded_calibration_stereo::core
