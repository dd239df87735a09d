// Build tool: a SPIR-V binary as a C++ header, `const uint32_t NAME[] = {...};` (what glslang's --vn writes, for
// modules that spirv-opt has rewritten after glslang). Usage: tessera_embed_spirv IN.spv NAME OUT.h
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <vector>

int main(int argc, char** argv) {
    if (argc != 4) {
        std::fprintf(stderr, "usage: %s IN.spv NAME OUT.h\n", argv[0]);
        return 2;
    }
    std::ifstream in(argv[1], std::ios::binary);
    if (!in) {
        std::perror(argv[1]);
        return 1;
    }
    const std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (bytes.size() < 20 || bytes.size() % 4 != 0 || uint8_t(bytes[0]) != 0x03 || uint8_t(bytes[3]) != 0x07) {
        std::fprintf(stderr, "%s: not a SPIR-V module (%zu bytes)\n", argv[1], bytes.size());
        return 1;
    }
    std::FILE* out = std::fopen(argv[3], "w");
    if (!out) {
        std::perror(argv[3]);
        return 1;
    }
    std::fprintf(out, "// %s: SPIR-V embedded by tessera_embed_spirv.\n#pragma once\n#include <cstdint>\nconst uint32_t %s[] = {", argv[2], argv[2]);
    for (size_t i = 0; i < bytes.size(); i += 4) {
        uint32_t word = 0;
        for (int k = 3; k >= 0; --k) word = word << 8 | uint8_t(bytes[i + k]);  // SPIR-V files are little-endian words
        std::fprintf(out, "%s0x%08x,", i % 32 == 0 ? "\n    " : "", word);
    }
    std::fprintf(out, "\n};\n");
    return std::fclose(out) == 0 ? 0 : 1;
}
