/* Opens a .nmat file, prints what it holds, decodes a few texels, and writes mip 0 of its first
 * channels as an image: PPM for 3+ channels, PGM for 1–2. Usage: example IN.nmat OUT_BASENAME */
#include "nmat.h"

#include <stdio.h>
#include <stdlib.h>

static int fail(const char *what, nmat_status status) {
    char message[128], detail[256];
    nmat_status_message(status, (uint8_t *)message, sizeof message);
    nmat_last_error((uint8_t *)detail, sizeof detail);
    fprintf(stderr, "%s: %s (%s)\n", what, message, detail);
    return 1;
}

int main(int argc, char **argv) {
    FILE *f;
    long size;
    uint8_t *data, *pixels;
    nmat_material *m = NULL;
    nmat_info info;
    nmat_status s;
    uint32_t c, channels, mask;
    size_t row, total;
    char path[1024];
    if (argc != 3) {
        fprintf(stderr, "usage: %s IN.nmat OUT_BASENAME\n", argv[0]);
        return 2;
    }
    f = fopen(argv[1], "rb");
    if (!f) return perror(argv[1]), 1;
    fseek(f, 0, SEEK_END);
    size = ftell(f);
    fseek(f, 0, SEEK_SET);
    data = (uint8_t *)malloc((size_t)size);
    if (!data || fread(data, 1, (size_t)size, f) != (size_t)size) return perror("read"), 1;
    fclose(f);

    s = nmat_material_open(data, (size_t)size, &m); /* copies: data may be freed now */
    free(data);
    if (s != NMAT_OK) return fail(argv[1], s);
    nmat_material_info(m, &info);
    printf("%s: %ux%u, %u mips, %u channels, %.3f bits per pixel per channel\n", argv[1], info.width,
           info.height, info.mip_count, info.channel_count, info.bppc);
    for (c = 0; c < info.channel_count; c++) {
        nmat_channel_info ch;
        nmat_material_channel(m, c, &ch);
        printf("  channel %2u %-16s [%g, %g]\n", c, (const char *)ch.name, ch.range_min, ch.range_max);
    }
    {
        float v[16];
        uint8_t codes[16];
        nmat_decode_texel(m, 7, 3, 0, 0xFFFF, NMAT_MODE_FLOAT, v, 16);
        nmat_decode_texel_u8(m, 7, 3, 0, 0xFFFF, codes, 16);
        printf("texel (7,3) mip 0, channel 0: float %.4f, integer code %u\n", v[0], codes[0]);
    }
    channels = info.channel_count >= 3 ? 3 : 1;
    mask = (1u << channels) - 1;
    s = nmat_required_size(m, info.width, info.height, mask, 1, 0, &row, &total);
    if (s != NMAT_OK) return fail("size", s);
    pixels = (uint8_t *)malloc(total);
    if (!pixels) return 1;
    s = nmat_decode_region_u8(m, 0, 0, 0, info.width, info.height, mask, pixels, row, total);
    if (s != NMAT_OK) return fail("decode", s);
    snprintf(path, sizeof path, "%s.%s", argv[2], channels == 3 ? "ppm" : "pgm");
    f = fopen(path, "wb");
    if (!f) return perror(path), 1;
    fprintf(f, "%s\n%u %u\n255\n", channels == 3 ? "P6" : "P5", info.width, info.height);
    fwrite(pixels, 1, total, f);
    fclose(f);
    printf("wrote %s\n", path);
    free(pixels);
    nmat_material_free(m);
    return 0;
}
