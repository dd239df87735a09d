// Patch raster, fragment stage (raster_fragment.h), with micro-triangles' masks (tessellation.h).
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_shader_atomic_int64 : require
#include "frame.h"
#include "surface.h"
#include "tessellation.h"
#include "raster.h"
#include "raster_fragment.h"
