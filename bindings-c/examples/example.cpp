// C++17 use of the nmat C API: an RAII handle, a memory-mapped-style borrowed open, and a sampled
// row of texels. Usage: example_cpp IN.nmat
#include "nmat.h"

#include <cstdio>
#include <fstream>
#include <iterator>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

struct MaterialDeleter {
    void operator()(nmat_material* m) const noexcept { nmat_material_free(m); }
};
using Material = std::unique_ptr<nmat_material, MaterialDeleter>;

void check(nmat_status s, const char* what) {
    if (s == NMAT_OK) return;
    std::string detail(nmat_last_error(nullptr, 0), '\0');
    nmat_last_error(reinterpret_cast<uint8_t*>(detail.data()), detail.size());
    throw std::runtime_error(std::string(what) + ": " + detail.c_str());
}

}  // namespace

int main(int argc, char** argv) try {
    if (argc != 2) {
        std::fprintf(stderr, "usage: %s IN.nmat\n", argv[0]);
        return 2;
    }
    std::ifstream in(argv[1], std::ios::binary);
    const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    nmat_material* raw = nullptr;
    // Borrowed: `bytes` outlives `material` (declared first, destroyed last).
    check(nmat_material_open_borrowed(bytes.data(), bytes.size(), &raw), argv[1]);
    const Material material(raw);
    nmat_info info{};
    check(nmat_material_info(material.get(), &info), "info");
    std::printf("%ux%u, %u channels, library %u.%u.%u\n", info.width, info.height, info.channel_count,
                NMAT_VERSION_MAJOR, NMAT_VERSION_MINOR, NMAT_VERSION_PATCH);
    const float random[3] = {0.25f, 0.75f, 0.5f};
    for (int i = 0; i < 4; ++i) {
        float rgb[16] = {};
        const float u = (static_cast<float>(i) + 0.5f) / 4.0f;
        check(nmat_sample(material.get(), u, 0.5f, 0.5f, NMAT_FILTER_STOCHASTIC, NMAT_MODE_INTEGER, random,
                          0x1, rgb, 16),
              "sample");
        std::printf("sample u=%.3f: %.4f\n", u, rgb[0]);
    }
    return 0;
} catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
}
