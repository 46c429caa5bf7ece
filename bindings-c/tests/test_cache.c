/* The tile cache through the C API: a neural and an indexed-JPEG material in one cache; every
 * resolved value equals nmat_sample in integer mode (an independent path: direct decoding);
 * frame counters, a second frame from the cache, eviction, a cache too small, decoding on
 * threads, footprints marked in one batch, refusals, calls that overlap where they must not
 * (NMAT_CACHE_BUSY), materials freed before their cache. Compiled as C99 and as C++17 under ASan+UBSan (see ../Makefile).
 * Usage: test_cache NEURAL.nmat JPEG.nmat */
#include "nmat.h"
#include "check.h"

#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { LOOKUPS = 2000 };

typedef struct {
    uint32_t material, filter, mask;
    float u, v, lod, random[3];
} lookup;

static uint64_t rng_state = 0x9E3779B97F4A7C15ull;
static float unit(void) {
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (float)(rng_state >> 40) / 16777216.0f;
}

static size_t popcount(uint32_t v) {
    size_t n = 0;
    for (; v; v &= v - 1) n++;
    return n;
}

static void make_lookups(lookup *l, size_t n, const nmat_info *info) {
    size_t i;
    for (i = 0; i < n; i++) {
        uint32_t m = (uint32_t)(unit() * 2.0f) & 1;
        uint32_t all = (1u << info[m].channel_count) - 1;
        l[i].material = m;
        l[i].filter = (uint32_t)(unit() * 4.0f) & 3;
        l[i].mask = 1 + (uint32_t)(unit() * (float)(all - 1));
        l[i].u = unit() * 1.6f - 0.3f;
        l[i].v = unit() * 1.6f - 0.3f;
        l[i].lod = unit() * (float)(info[m].mip_count + 1) - 0.5f;
        l[i].random[0] = unit();
        l[i].random[1] = unit();
        l[i].random[2] = unit();
    }
}

/* One frame of `n` lookups; returns how many resolved values differ from nmat_sample. */
static int run_frame(nmat_cache *cache, const nmat_material *const *m, const lookup *l, size_t n,
                     uint32_t threads, nmat_frame_stats *stats) {
    size_t i;
    int differ = 0;
    uint32_t decoded = 0;
    CHECK(nmat_cache_begin_frame(cache) == NMAT_OK);
    for (i = 0; i < n; i++) {
        CHECK(nmat_cache_mark(cache, l[i].material, l[i].u, l[i].v, l[i].lod, l[i].filter,
                              l[i].random) == NMAT_OK);
    }
    CHECK(nmat_cache_decode_missing(cache, threads, &decoded) == NMAT_OK);
    for (i = 0; i < n; i++) {
        float got[16], want[16];
        CHECK(nmat_cache_resolve(cache, l[i].material, l[i].u, l[i].v, l[i].lod, l[i].filter,
                                 l[i].random, l[i].mask, got, 16) == NMAT_OK);
        CHECK(nmat_sample(m[l[i].material], l[i].u, l[i].v, l[i].lod, l[i].filter,
                          NMAT_MODE_INTEGER, l[i].random, l[i].mask, want, 16) == NMAT_OK);
        differ += memcmp(got, want, sizeof(float) * popcount(l[i].mask)) != 0;
    }
    CHECK(nmat_cache_end_frame(cache, stats) == NMAT_OK);
    CHECK(stats->decoded == decoded);
    return differ;
}

static void test_frames(const nmat_material *const *m, const nmat_info *info) {
    static lookup l[LOOKUPS];
    nmat_cache *cache = NULL;
    nmat_frame_stats first, second, third;
    make_lookups(l, LOOKUPS, info);
    CHECK(nmat_cache_create(m, 2, 1024, &cache) == NMAT_OK && cache != NULL);
    if (!cache) return;
    CHECK(run_frame(cache, m, l, LOOKUPS, 1, &first) == 0);
    CHECK(first.frame == 1 && first.marked > 10 && first.hits == 0);
    CHECK(first.decoded == first.marked && first.resolve_misses == 0 && first.overflowed == 0);
    CHECK(first.decoded_texels <= first.decoded * 256 && first.decoded_texels > 0);
    /* The same lookups again, decoded on two threads: everything comes from the cache. */
    CHECK(run_frame(cache, m, l, LOOKUPS, 2, &second) == 0);
    CHECK(second.frame == 2 && second.marked == first.marked && second.hits == first.marked);
    CHECK(second.decoded == 0 && second.resolve_misses == 0 && second.evicted == 0);
    /* A frame of a few of them: the tiles only the others read are evicted at its end. */
    CHECK(run_frame(cache, m, l, LOOKUPS / 100, 0, &third) == 0);
    CHECK(third.decoded == 0 && third.hits == third.marked && third.marked < first.marked);
    CHECK(third.evicted == first.marked - third.marked);
    /* Texel marks: a tile of mip 1 of the neural material (clamped or wrapped coordinates). */
    CHECK(nmat_cache_begin_frame(cache) == NMAT_OK);
    CHECK(nmat_cache_mark_texel(cache, 0, -3, 1000, 1) == NMAT_OK);
    CHECK(nmat_cache_stats(cache, &third) == NMAT_OK && third.marked == 1);
    CHECK(nmat_cache_end_frame(cache, NULL) == NMAT_OK);
    nmat_cache_free(cache);

    /* Three tiles for a frame that needs many more: still the same values, counted. */
    CHECK(nmat_cache_create(m, 2, 3, &cache) == NMAT_OK && cache != NULL);
    if (!cache) return;
    CHECK(run_frame(cache, m, l, LOOKUPS / 4, 2, &first) == 0);
    CHECK(first.marked == 3 && first.overflowed > 0 && first.resolve_misses > 0);
    nmat_cache_free(cache);
}

/* The footprints listed first (as threads would), then marked in one call: the same tiles as
 * marking lookup by lookup, and the same values. */
static void test_batch_marking(const nmat_material *const *m, const nmat_info *info) {
    static lookup l[LOOKUPS];
    static nmat_tile_key keys[LOOKUPS * 8];
    nmat_cache *one = NULL, *batch = NULL;
    nmat_frame_stats by_lookup, batched;
    size_t i, n = 0, count = 0;
    int differ = 0;
    make_lookups(l, LOOKUPS, info);
    CHECK(nmat_cache_create(m, 2, 1024, &one) == NMAT_OK);
    CHECK(nmat_cache_create(m, 2, 1024, &batch) == NMAT_OK);
    if (!one || !batch) return;
    CHECK(run_frame(one, m, l, LOOKUPS, 1, &by_lookup) == 0);
    CHECK(nmat_cache_begin_frame(batch) == NMAT_OK);
    for (i = 0; i < LOOKUPS; i++) {
        CHECK(nmat_cache_footprint(batch, l[i].material, l[i].u, l[i].v, l[i].lod, l[i].filter,
                                   l[i].random, keys + n, 8, &count) == NMAT_OK);
        CHECK(count >= 1 && count <= 8);
        n += count;
    }
    CHECK(nmat_cache_stats(batch, &batched) == NMAT_OK && batched.marked == 0);
    CHECK(nmat_cache_mark_tiles(batch, keys, n) == NMAT_OK);
    CHECK(nmat_cache_decode_missing(batch, 2, NULL) == NMAT_OK);
    for (i = 0; i < LOOKUPS; i++) {
        float got[16], want[16];
        CHECK(nmat_cache_resolve(batch, l[i].material, l[i].u, l[i].v, l[i].lod, l[i].filter,
                                 l[i].random, l[i].mask, got, 16) == NMAT_OK);
        CHECK(nmat_sample(m[l[i].material], l[i].u, l[i].v, l[i].lod, l[i].filter,
                          NMAT_MODE_INTEGER, l[i].random, l[i].mask, want, 16) == NMAT_OK);
        differ += memcmp(got, want, sizeof(float) * popcount(l[i].mask)) != 0;
    }
    CHECK(differ == 0);
    CHECK(nmat_cache_end_frame(batch, &batched) == NMAT_OK);
    CHECK(batched.marked == by_lookup.marked && batched.decoded == by_lookup.decoded);
    CHECK(batched.resolve_misses == 0 && n > batched.marked);
    /* Too little room for a trilinear footprint, and keys the materials do not have. */
    keys[0].material = 5;
    CHECK(nmat_cache_mark_tiles(batch, keys, 1) == NMAT_BAD_ARGUMENT);
    keys[0].material = 0;
    keys[0].mip = 30;
    CHECK(nmat_cache_mark_tiles(batch, keys, 1) == NMAT_BAD_ARGUMENT);
    CHECK(nmat_cache_footprint(batch, 0, 0.31f, 0.77f, 0.5f, NMAT_FILTER_TRILINEAR, NULL, keys, 1,
                               &count) == NMAT_BUFFER_TOO_SMALL);
    CHECK(nmat_cache_footprint(batch, 0, 0.31f, 0.77f, 0.5f, NMAT_FILTER_TRILINEAR, NULL, keys, 8,
                               NULL) == NMAT_NULL_ARGUMENT);
    nmat_cache_free(one);
    nmat_cache_free(batch);
}

static void test_refusals(const nmat_material *const *m) {
    nmat_cache *cache = NULL;
    float out[16];
    const float random[3] = {0.5f, 0.5f, 0.5f};
    uint8_t detail[200];
    CHECK(nmat_cache_create(m, 2, 0, &cache) == NMAT_BAD_ARGUMENT && cache == NULL);
    CHECK(nmat_last_error(detail, sizeof detail) > 1 && strstr((const char *)detail, "CacheMemory") != NULL);
    CHECK(nmat_cache_create(m, 0, 8, &cache) == NMAT_BAD_ARGUMENT && cache == NULL);
    CHECK(nmat_cache_create(NULL, 2, 8, &cache) == NMAT_NULL_ARGUMENT);
    CHECK(nmat_cache_create(m, 2, 8, NULL) == NMAT_NULL_ARGUMENT);
    /* Beyond the limit of 2^32 - 2 tiles: refused before anything is allocated. */
    CHECK(nmat_cache_create(m, 2, SIZE_MAX / 2, &cache) == NMAT_BAD_ARGUMENT && cache == NULL);
    CHECK(nmat_last_error(detail, sizeof detail) > 1 && strstr((const char *)detail, "limit 4294967294") != NULL);
    CHECK(nmat_cache_create(m, 2, 8, &cache) == NMAT_OK);
    if (!cache) return;
    CHECK(nmat_cache_begin_frame(NULL) == NMAT_NULL_ARGUMENT);
    CHECK(nmat_cache_mark(cache, 2, 0.5f, 0.5f, 0.0f, NMAT_FILTER_BILINEAR, NULL) == NMAT_BAD_ARGUMENT);
    CHECK(nmat_cache_mark(cache, 0, 0.5f, 0.5f, 0.0f, 7, NULL) == NMAT_BAD_ARGUMENT);
    CHECK(nmat_cache_mark(cache, 0, 0.5f, 0.5f, 0.0f, NMAT_FILTER_STOCHASTIC, NULL) == NMAT_NULL_ARGUMENT);
    CHECK(nmat_cache_mark(cache, 0, 0.5f, 0.5f, 0.0f, NMAT_FILTER_STOCHASTIC, random) == NMAT_OK);
    CHECK(nmat_cache_mark_texel(cache, 0, 0, 0, 99) == NMAT_BAD_ARGUMENT);
    CHECK(nmat_cache_resolve(cache, 0, 0.5f, 0.5f, 0.0f, NMAT_FILTER_NEAREST, NULL, 0, out, 16) == NMAT_BAD_ARGUMENT);
    CHECK(nmat_cache_resolve(cache, 1, 0.5f, 0.5f, 0.0f, NMAT_FILTER_NEAREST, NULL, 0x7, out, 2) == NMAT_BUFFER_TOO_SMALL);
    CHECK(nmat_cache_resolve(cache, 1, 0.5f, 0.5f, 0.0f, NMAT_FILTER_NEAREST, NULL, 0x7, NULL, 16) == NMAT_NULL_ARGUMENT);
    CHECK(nmat_cache_decode_missing(cache, 0, NULL) == NMAT_OK);
    CHECK(nmat_cache_stats(cache, NULL) == NMAT_NULL_ARGUMENT);
    CHECK(nmat_cache_end_frame(cache, NULL) == NMAT_OK);
    nmat_cache_free(cache);
    nmat_cache_free(NULL);
}

/* Calls that overlap where they must not: 8 threads marking, one decoding, one resolving and
 * one listing footprints, all on one cache at once. The calls that change the cache (mark,
 * decode_missing) must not overlap with any other, so some are refused with NMAT_CACHE_BUSY; no
 * call may fail otherwise, and nothing may race (ASan and UBSan watch the library). Afterwards
 * the cache works as before. */
enum { MARKERS = 8, WORKERS = MARKERS + 3, MAX_ROUNDS = 200000, ENOUGH_BUSY = 200 };

typedef struct {
    nmat_cache *cache;
    const lookup *l;
    int role; /* 0 marks, 1 decodes, 2 resolves, 3 lists footprints */
    long ok, busy, other;
    int busy_detail_ok;
} worker;

static pthread_mutex_t busy_lock = PTHREAD_MUTEX_INITIALIZER;
static long busy_seen = 0;

static int busy_count(long add) {
    long n;
    pthread_mutex_lock(&busy_lock);
    busy_seen += add;
    n = busy_seen;
    pthread_mutex_unlock(&busy_lock);
    return n >= ENOUGH_BUSY;
}

static void *work(void *arg) {
    worker *w = (worker *)arg;
    long i;
    /* Until every role has seen enough refusals in all, or a generous bound. */
    for (i = 0; i < MAX_ROUNDS && !busy_count(0); i++) {
        const lookup *p = &w->l[(size_t)(i * 7 + w->role) % LOOKUPS];
        float out[16];
        nmat_tile_key keys[8];
        size_t count = 0;
        nmat_status s;
        switch (w->role) {
        case 0:
            s = nmat_cache_mark(w->cache, p->material, p->u, p->v, p->lod, p->filter, p->random);
            break;
        case 1:
            s = nmat_cache_decode_missing(w->cache, 1, NULL);
            break;
        case 2:
            s = nmat_cache_resolve(w->cache, p->material, p->u, p->v, p->lod, p->filter, p->random,
                                   p->mask, out, 16);
            break;
        default:
            s = nmat_cache_footprint(w->cache, p->material, p->u, p->v, p->lod, p->filter,
                                     p->random, keys, 8, &count);
            break;
        }
        if (s == NMAT_OK) {
            w->ok++;
        } else if (s == NMAT_CACHE_BUSY) {
            uint8_t detail[300];
            if (w->busy++ == 0) {
                nmat_last_error(detail, sizeof detail);
                w->busy_detail_ok = strstr((const char *)detail, "another thread is using this cache") != NULL;
            }
            busy_count(1);
        } else {
            w->other++;
        }
    }
    return NULL;
}

static void test_overlapping_calls(const nmat_material *const *m, const nmat_info *info) {
    static lookup l[LOOKUPS];
    pthread_t threads[WORKERS];
    worker workers[WORKERS];
    nmat_cache *cache = NULL;
    nmat_frame_stats stats, after;
    long busy = 0, ok = 0;
    int i;
    make_lookups(l, LOOKUPS, info);
    CHECK(nmat_cache_create(m, 2, 1024, &cache) == NMAT_OK && cache != NULL);
    if (!cache) return;
    CHECK(nmat_cache_begin_frame(cache) == NMAT_OK);
    for (i = 0; i < WORKERS; i++) {
        workers[i].cache = cache;
        workers[i].l = l;
        workers[i].role = i < MARKERS ? 0 : i - MARKERS + 1;
        workers[i].ok = workers[i].busy = workers[i].other = 0;
        workers[i].busy_detail_ok = 1;
        CHECK(pthread_create(&threads[i], NULL, work, &workers[i]) == 0);
    }
    for (i = 0; i < WORKERS; i++) {
        CHECK(pthread_join(threads[i], NULL) == 0);
        CHECK(workers[i].other == 0);
        CHECK(workers[i].busy_detail_ok);
        busy += workers[i].busy;
        ok += workers[i].ok;
    }
    printf("test_cache: overlapping calls: %ld refused with NMAT_CACHE_BUSY, %ld done\n", busy, ok);
    CHECK(busy > 0 && ok > 0);
    /* The frame those threads marked ends with sane books, and the next frame is exact. */
    CHECK(nmat_cache_decode_missing(cache, 2, NULL) == NMAT_OK);
    CHECK(nmat_cache_end_frame(cache, &stats) == NMAT_OK);
    CHECK(stats.frame == 1 && stats.marked <= 1024 && stats.overflowed == 0);
    CHECK(stats.decoded <= stats.marked && stats.hits == 0);
    CHECK(run_frame(cache, m, l, LOOKUPS, 2, &after) == 0);
    CHECK(after.frame == 2 && after.marked > 0 && after.overflowed == 0);
    CHECK(after.hits + after.decoded == after.marked && after.resolve_misses == 0);
    nmat_cache_free(cache);
}

/* The cache holds its own reference to each material: the caller may free its handles first
 * (ASan reports a use after free if it did not). Its values still equal nmat_sample on other
 * handles of the same files. */
static void test_materials_freed_first(char **paths, const nmat_material *const *m,
                                       const nmat_info *info) {
    static lookup l[LOOKUPS / 10];
    nmat_material *own[2] = {NULL, NULL};
    nmat_cache *cache = NULL;
    nmat_frame_stats stats;
    int i;
    for (i = 0; i < 2; i++) {
        size_t len = 0;
        uint8_t *bytes = read_file(paths[i], &len);
        CHECK(bytes != NULL && nmat_material_open(bytes, len, &own[i]) == NMAT_OK);
        free(bytes);
    }
    make_lookups(l, LOOKUPS / 10, info);
    if (own[0] && own[1]) {
        CHECK(nmat_cache_create((const nmat_material *const *)own, 2, 256, &cache) == NMAT_OK);
    }
    for (i = 0; i < 2; i++) nmat_material_free(own[i]);
    if (!cache) return;
    CHECK(run_frame(cache, m, l, LOOKUPS / 10, 2, &stats) == 0);
    CHECK(stats.decoded > 0 && stats.decoded == stats.marked);
    nmat_cache_free(cache);
}

int main(int argc, char **argv) {
    nmat_material *m[2] = {NULL, NULL};
    nmat_info info[2];
    int i;
    if (argc != 3) {
        fprintf(stderr, "usage: %s NEURAL.nmat JPEG.nmat\n", argv[0]);
        return 2;
    }
    for (i = 0; i < 2; i++) {
        size_t len = 0;
        uint8_t *bytes = read_file(argv[i + 1], &len);
        if (!bytes) {
            fprintf(stderr, "cannot read %s\n", argv[i + 1]);
            return 2;
        }
        CHECK(nmat_material_open(bytes, len, &m[i]) == NMAT_OK);
        free(bytes);
        if (!m[i]) return 1;
        CHECK(nmat_material_info(m[i], &info[i]) == NMAT_OK);
    }
    test_frames((const nmat_material *const *)m, info);
    test_batch_marking((const nmat_material *const *)m, info);
    test_refusals((const nmat_material *const *)m);
    test_overlapping_calls((const nmat_material *const *)m, info);
    test_materials_freed_first(argv + 1, (const nmat_material *const *)m, info);
    for (i = 0; i < 2; i++) nmat_material_free(m[i]);
    if (failures) {
        fprintf(stderr, "%d check(s) failed\n", failures);
        return 1;
    }
    printf("test_cache: ok\n");
    return 0;
}
