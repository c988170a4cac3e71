#pragma once
// Error thrown by every core loader and validator. The message always names the offending
// parameter (as a dotted path such as "cameras.left.fx") and the problem.
#include <stdexcept>
#include <string>

namespace ecs {

class ConfigError : public std::runtime_error {
 public:
  ConfigError(const std::string& parameter, const std::string& problem)
      : std::runtime_error(parameter + ": " + problem), parameter_(parameter) {}
  const std::string& parameter() const { return parameter_; }

 private:
  std::string parameter_;
};

}  // namespace ecs
