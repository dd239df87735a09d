// Validation of BuildSettings: a bad value is reported by the setting's name before anything is built.
#include "tessera/builder.h"

#include <cfloat>
#include <sstream>

namespace tessera {
namespace {

[[noreturn]] void reject(const char* name, double value, const char* wanted) {
    std::ostringstream message;
    message << "build setting " << name << " must be " << wanted << ", not " << value;
    throw std::invalid_argument(message.str());
}

void check_range(const char* name, float value, double lo, double hi, const char* wanted) {
    if (!(value >= lo && value <= hi)) reject(name, value, wanted);  // NaN fails both comparisons
}

}  // namespace

void validate_settings(const BuildSettings& s) {
    if (s.positionPrecision != BuildSettings::kAutoPrecision && (s.positionPrecision < -64 || s.positionPrecision > 64))
        reject("positionPrecision", s.positionPrecision, "between -64 and 64 (log2 of the grid step), or automatic");
    check_range("keepTrianglePercent", s.keepTrianglePercent, 0, 100, "a percentage between 0 and 100");
    check_range("fallbackTrianglePercent", s.fallbackTrianglePercent, 0, 100, "a percentage between 0 and 100");
    // Finite: infinity could only mean "the coarsest level", which any large finite value says as well.
    check_range("trimRelativeError", s.trimRelativeError, 0, FLT_MAX, "a finite number >= 0 (percent of the mesh size)");
    check_range("fallbackRelativeError", s.fallbackRelativeError, 0, FLT_MAX, "a finite number >= 0 (percent of the mesh size)");
    check_range("maxEdgeLengthFactor", s.maxEdgeLengthFactor, 0, FLT_MAX, "a finite number >= 0 (0: no limit)");
}

}  // namespace tessera
