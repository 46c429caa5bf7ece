/* The C API on an indexed-JPEG material. Compiled as C99 and as C++17 under ASan+UBSan (see
 * ../Makefile). Usage: test_jpeg FIXTURE.nmat EXPECTED.u8
 * FIXTURE is tests/fixtures/jpeg/pattern_420_37x21.nmat (`nmat index` of the .jpg beside it: 37×21,
 * 4:2:0, restart markers); EXPECTED is libjpeg-turbo's `djpeg -dct int -nosmooth` of that .jpg
 * (RGB samples, no header): an independent decoder (tests/fixtures/jpeg/README.md). */
#include "nmat.h"
#include "check.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { W = 37, H = 21, C = 3 };

static void test_texels(const nmat_material *m, const uint8_t *expected) {
    nmat_info info;
    uint8_t codes[16], one[1];
    float values[16];
    int x, y, c, same = 1, subset = 1, wraps = 1;
    CHECK(nmat_material_info(m, &info) == NMAT_OK);
    CHECK(info.width == W && info.height == H && info.mip_count == 1 && info.channel_count == C);
    /* 2.1 as written by `nmat index --fixed-rate`, 2.2 packed. */
    CHECK((info.format_minor == 1 || info.format_minor == 2) && info.bppc > 0.0);
    for (y = 0; y < H; y++) {
        for (x = 0; x < W; x++) {
            const uint8_t *e = expected + (size_t)(y * W + x) * C;
            CHECK(nmat_decode_texel_u8(m, x, y, 0, 0xFFFF, codes, sizeof codes) == NMAT_OK);
            same &= memcmp(codes, e, C) == 0;
            /* One channel alone (bit 1: G) is the same code. */
            CHECK(nmat_decode_texel_u8(m, x, y, 0, 1u << 1, one, 1) == NMAT_OK);
            subset &= one[0] == e[1];
            /* The material wraps: x − W is x. */
            CHECK(nmat_decode_texel_u8(m, (int64_t)x - W, y, 0, 0xFFFF, codes, sizeof codes) == NMAT_OK);
            wraps &= memcmp(codes, e, C) == 0;
        }
    }
    CHECK(same && subset && wraps);
    /* Values through the float API (either mode) are code / 255 in the channel range [0, 1]. */
    for (c = 0; c <= 1; c++) {
        CHECK(nmat_decode_texel(m, 20, 13, 0, 0xFFFF, (uint32_t)c, values, 16) == NMAT_OK);
        CHECK(values[2] == expected[(13 * W + 20) * C + 2] / 255.0f);
    }
    /* Nearest sampling at a texel's centre is that texel. */
    CHECK(nmat_sample(m, (20 + 0.5f) / W, (13 + 0.5f) / H, 0.0f, NMAT_FILTER_NEAREST,
                      NMAT_MODE_INTEGER, NULL, 0xFFFF, values, 16) == NMAT_OK);
    CHECK(values[0] == expected[(13 * W + 20) * C] / 255.0f);
    CHECK(nmat_sample(m, 0.37f, 0.61f, 0.0f, NMAT_FILTER_BILINEAR, NMAT_MODE_INTEGER, NULL, 0xFFFF,
                      values, 16) == NMAT_OK);
    CHECK(values[0] >= 0.0f && values[0] <= 1.0f);
    /* A mip the material does not have, and a buffer too small, are refused. */
    CHECK(nmat_decode_texel_u8(m, 0, 0, 1, 0xFFFF, codes, sizeof codes) == NMAT_BAD_ARGUMENT);
    CHECK(nmat_decode_texel_u8(m, 0, 0, 0, 0xFFFF, codes, 2) != NMAT_OK);
}

static void test_regions(const nmat_material *m, const uint8_t *expected) {
    /* The whole image packed, then an odd rectangle with a padded pitch: every row equals the
     * expected samples, and the padding is untouched. */
    uint8_t whole[W * H * C], part[9 * (11 * C + 5)];
    const uint32_t x0 = 13, y0 = 7, w = 11, h = 9, pitch = 11 * C + 5;
    uint32_t y;
    CHECK(nmat_decode_region_u8(m, 0, 0, 0, W, H, 0xFFFF, whole, 0, sizeof whole) == NMAT_OK);
    CHECK(memcmp(whole, expected, sizeof whole) == 0);
    memset(part, 0xEE, sizeof part);
    CHECK(nmat_decode_region_u8(m, 0, x0, y0, w, h, 0xFFFF, part, pitch, (h - 1) * pitch + w * C) ==
          NMAT_OK);
    for (y = 0; y < h; y++) {
        CHECK(memcmp(part + y * pitch, expected + ((y0 + y) * W + x0) * C, w * C) == 0);
        if (y + 1 < h) CHECK(part[y * pitch + w * C] == 0xEE);
    }
    /* Past the mip's edge: refused. */
    CHECK(nmat_decode_region_u8(m, 0, W - 2, 0, 3, 1, 0xFFFF, part, 0, sizeof part) ==
          NMAT_BAD_ARGUMENT);
}

static void test_damaged(const uint8_t *data, size_t len) {
    /* Every truncation is refused with a status, never a crash. */
    size_t n;
    nmat_material *m = NULL;
    for (n = 0; n < len; n += 7) {
        uint8_t *copy = (uint8_t *)malloc(n + 1);
        memcpy(copy, data, n);
        CHECK(nmat_material_open(copy, n, &m) != NMAT_OK && m == NULL);
        free(copy);
    }
}

int main(int argc, char **argv) {
    size_t len = 0, expected_len = 0;
    uint8_t *data, *expected;
    nmat_material *m = NULL;
    if (argc != 3 && argc != 4) {
        fprintf(stderr, "usage: %s FIXTURE.nmat EXPECTED.u8 [PACKED.nmat]\n", argv[0]);
        return 2;
    }
    data = read_file(argv[1], &len);
    expected = read_file(argv[2], &expected_len);
    if (!data || !expected || expected_len != (size_t)W * H * C) {
        fprintf(stderr, "cannot read %s or %s (%d × %d × %d samples)\n", argv[1], argv[2], W, H, C);
        return 2;
    }
    CHECK(nmat_material_open(data, len, &m) == NMAT_OK);
    if (m) {
        test_texels(m, expected);
        test_regions(m, expected);
    }
    test_damaged(data, len);
    nmat_material_free(m);
    if (argc == 4) {
        /* The same material packed (format 2.2, streams without their index): the index is
         * rebuilt when it is opened, and every texel decodes the same. */
        size_t packed_len = 0;
        uint8_t *packed = read_file(argv[3], &packed_len);
        nmat_material *p = NULL;
        nmat_info info;
        CHECK(packed != NULL && packed_len < len);
        if (packed) CHECK(nmat_material_open_borrowed(packed, packed_len, &p) == NMAT_OK);
        free(packed); /* the handle owns the unpacked file */
        if (p) {
            test_texels(p, expected);
            test_regions(p, expected);
            CHECK(nmat_material_info(p, &info) == NMAT_OK && info.format_minor == 2);
        }
        nmat_material_free(p);
    }
    free(data);
    free(expected);
    if (failures) {
        fprintf(stderr, "%d check(s) failed\n", failures);
        return 1;
    }
    printf("test_jpeg: all checks passed\n");
    return 0;
}
