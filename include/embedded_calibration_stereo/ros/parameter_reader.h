#pragma once
// The one reader of the nodelets' private parameters. An absent parameter takes its default; a
// present one of the wrong type is refused (core::ConfigError naming it), never silently replaced
// by the default as NodeHandle::param() does. Types follow XmlRpc strictly:
//   int     an XmlRpc int only (5.0 is refused, where roscpp's getParam(int) would round it);
//   double  an XmlRpc double or int (a finite value);
//   bool    an XmlRpc bool only (not 0/1, not "true");
//   string  an XmlRpc string only.
// The nodelets read every parameter at the start of onInit and, on a ConfigError, log
// "<Nodelet> cannot start: <parameter>: <problem>" at FATAL and rethrow so that the manager
// refuses to load them.
//
// Threads: none of its own; reading is const and touches the parameter server (or the lookup).
#include <ros/node_handle.h>
#include <xmlrpcpp/XmlRpcValue.h>

#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/core/io/config_error.h"

namespace embedded_calibration_stereo {

class ParameterReader {
 public:
  // Looks `name` up; false when it is not set.
  using Lookup = std::function<bool(const std::string& name, XmlRpc::XmlRpcValue* value)>;

  // The parameters in `nh`'s namespace on the parameter server (normally the private handle).
  explicit ParameterReader(const ros::NodeHandle& nh);
  // Parameters from any lookup (the unit tests use a map, without a master).
  explicit ParameterReader(Lookup lookup);

  bool has(const std::string& name) const;

  // The value of `name`, or `fallback` when it is not set. T: bool, int, double or std::string.
  template <class T>
  T get(const std::string& name, const T& fallback) const;
  std::string get(const std::string& name, const char* fallback) const { return get<std::string>(name, fallback); }

  // The value of `name`; "missing" when it is not set.
  template <class T>
  T required(const std::string& name) const;

  // get() of a value that must lie in [min, max].
  template <class T>
  T inRange(const std::string& name, const T& fallback, const T& min, const T& max) const;
  // get() of a value that must be >= min.
  template <class T>
  T atLeast(const std::string& name, const T& fallback, const T& min) const;
  // get() of a string that must be one of `choices`.
  std::string choice(const std::string& name, const std::string& fallback,
                     const std::vector<std::string>& choices) const;

  // Refuses a present value that is not of the dynamic_reconfigure type `type` ("int", "double",
  // "str" or "bool"); an absent one is fine.
  void checkType(const std::string& name, const std::string& type) const;

 private:
  Lookup lookup_;
};

// Checks of values already read (or derived from several), throwing core::ConfigError(name, ...).
template <class T>
void checkRange(const std::string& name, const T& value, const T& min, const T& max);
template <class T>
void checkAtLeast(const std::string& name, const T& value, const T& min);
void checkChoice(const std::string& name, const std::string& value, const std::vector<std::string>& choices);

// Refuses a wrongly typed initial value of any parameter of a dynamic_reconfigure Config (its
// server would otherwise keep the cfg default without a word). Range problems are left to the
// server's clamping and the owner's callback.
template <class Config>
void checkReconfigureTypes(const ParameterReader& read) {
  for (const auto& description : Config::__getParamDescriptions__()) read.checkType(description->name, description->type);
}

// ---- implementation of the templates

namespace parameter_reader_detail {
template <class T>
std::string show(const T& value) {
  std::ostringstream s;
  s << value;
  return s.str();
}
}  // namespace parameter_reader_detail

template <class T>
T ParameterReader::inRange(const std::string& name, const T& fallback, const T& min, const T& max) const {
  const T value = get<T>(name, fallback);
  checkRange(name, value, min, max);
  return value;
}

template <class T>
T ParameterReader::atLeast(const std::string& name, const T& fallback, const T& min) const {
  const T value = get<T>(name, fallback);
  checkAtLeast(name, value, min);
  return value;
}

template <class T>
void checkRange(const std::string& name, const T& value, const T& min, const T& max) {
  using parameter_reader_detail::show;
  if (!(value >= min && value <= max))
    throw core::ConfigError(name, "must be in [" + show(min) + ", " + show(max) + "], got " + show(value));
}

template <class T>
void checkAtLeast(const std::string& name, const T& value, const T& min) {
  using parameter_reader_detail::show;
  if (!(value >= min)) throw core::ConfigError(name, "must be >= " + show(min) + ", got " + show(value));
}

}  // namespace embedded_calibration_stereo
