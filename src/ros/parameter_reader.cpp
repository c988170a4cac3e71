#include "embedded_calibration_stereo/ros/parameter_reader.h"

#include <cmath>
#include <utility>

namespace embedded_calibration_stereo {
namespace {

using XmlRpc::XmlRpcValue;

// What a refused value was, for the message: "the string 'five'", "5.0, a floating-point number".
std::string describe(XmlRpcValue& v) {
  switch (v.getType()) {
    case XmlRpcValue::TypeBoolean: return std::string("the boolean ") + (static_cast<bool>(v) ? "true" : "false");
    case XmlRpcValue::TypeInt: return "the integer " + std::to_string(static_cast<int>(v));
    case XmlRpcValue::TypeDouble: {
      std::string text = parameter_reader_detail::show(static_cast<double>(v));
      if (text.find_first_of(".enai") == std::string::npos) text += ".0";  // 5.0, not "5"
      return text + ", a floating-point number";
    }
    case XmlRpcValue::TypeString: return "the string '" + static_cast<std::string>(v) + "'";
    case XmlRpcValue::TypeArray: return "a list";
    case XmlRpcValue::TypeStruct: return "a dictionary";
    default: return "a value of another type";
  }
}

[[noreturn]] void refuse(const std::string& name, const std::string& expected, XmlRpcValue& v) {
  throw core::ConfigError(name, "must be " + expected + " (got " + describe(v) + ")");
}

void convert(const std::string& name, XmlRpcValue& v, bool* out) {
  if (v.getType() != XmlRpcValue::TypeBoolean) refuse(name, "true or false", v);
  *out = v;
}

void convert(const std::string& name, XmlRpcValue& v, int* out) {
  if (v.getType() != XmlRpcValue::TypeInt) refuse(name, "an integer", v);
  *out = v;
}

void convert(const std::string& name, XmlRpcValue& v, double* out) {
  if (v.getType() == XmlRpcValue::TypeInt) {
    *out = static_cast<int>(v);
    return;
  }
  if (v.getType() != XmlRpcValue::TypeDouble) refuse(name, "a number", v);
  *out = v;
  if (!std::isfinite(*out)) refuse(name, "a finite number", v);
}

void convert(const std::string& name, XmlRpcValue& v, std::string* out) {
  if (v.getType() != XmlRpcValue::TypeString) refuse(name, "a string", v);
  *out = static_cast<std::string>(v);
}

// "a, b or c"
std::string listed(const std::vector<std::string>& choices) {
  std::string out;
  for (size_t i = 0; i < choices.size(); ++i)
    out += (i == 0 ? "" : i + 1 == choices.size() ? " or " : ", ") + choices[i];
  return out;
}

}  // namespace

ParameterReader::ParameterReader(const ros::NodeHandle& nh)
    : lookup_([nh](const std::string& name, XmlRpcValue* value) { return nh.getParam(name, *value); }) {}

ParameterReader::ParameterReader(Lookup lookup) : lookup_(std::move(lookup)) {}

bool ParameterReader::has(const std::string& name) const {
  XmlRpcValue value;
  return lookup_(name, &value);
}

template <class T>
T ParameterReader::get(const std::string& name, const T& fallback) const {
  XmlRpcValue value;
  if (!lookup_(name, &value)) return fallback;
  T out;
  convert(name, value, &out);
  return out;
}

template <class T>
T ParameterReader::required(const std::string& name) const {
  XmlRpcValue value;
  if (!lookup_(name, &value)) throw core::ConfigError(name, "missing");
  T out;
  convert(name, value, &out);
  return out;
}

template bool ParameterReader::get<bool>(const std::string&, const bool&) const;
template int ParameterReader::get<int>(const std::string&, const int&) const;
template double ParameterReader::get<double>(const std::string&, const double&) const;
template std::string ParameterReader::get<std::string>(const std::string&, const std::string&) const;
template bool ParameterReader::required<bool>(const std::string&) const;
template int ParameterReader::required<int>(const std::string&) const;
template double ParameterReader::required<double>(const std::string&) const;
template std::string ParameterReader::required<std::string>(const std::string&) const;

std::string ParameterReader::choice(const std::string& name, const std::string& fallback,
                                    const std::vector<std::string>& choices) const {
  const std::string value = get<std::string>(name, fallback);
  checkChoice(name, value, choices);
  return value;
}

void ParameterReader::checkType(const std::string& name, const std::string& type) const {
  if (type == "int") {
    get<int>(name, 0);
  } else if (type == "double") {
    get<double>(name, 0.0);
  } else if (type == "str") {
    get<std::string>(name, "");
  } else if (type == "bool") {
    get<bool>(name, false);
  } else {
    throw core::ConfigError(name, "unknown parameter type '" + type + "'");
  }
}

void checkChoice(const std::string& name, const std::string& value, const std::vector<std::string>& choices) {
  for (const std::string& c : choices)
    if (value == c) return;
  throw core::ConfigError(name, "unknown value '" + value + "' (use " + listed(choices) + ")");
}

}  // namespace embedded_calibration_stereo
