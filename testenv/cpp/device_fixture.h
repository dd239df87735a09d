// A test suite that shares one Vulkan device and fails on any validation message (tests run with
// TESSERA_VALIDATION=1, which must then have activated the Khronos layer).
#pragma once

#include "tessera/device.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

class DeviceTest : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        device = new tessera::Device();
        const char* wanted = std::getenv("TESSERA_VALIDATION");
        if (wanted && std::string(wanted) == "1") EXPECT_TRUE(device->validation_enabled()) << "the validation layer must be active";
    }
    static void TearDownTestSuite() {
        EXPECT_EQ(device->validation_error_count(), 0u);
        for (auto& m : device->take_validation_messages()) ADD_FAILURE() << m;
        delete device;
        device = nullptr;
    }
    static inline tessera::Device* device = nullptr;
};
