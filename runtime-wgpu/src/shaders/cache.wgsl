// The tile cache's passes (cache.rs records them; docs/GPU.md, "The tile cache"): mark → compact
// and evict → plan → allocate → finish → clear → (decode: cache_decode.wgsl, jpeg.wgsl) →
// resolve (cache_resolve.wgsl). The table and the codes are laid out as cache_sample.wgsl says;
// `nmat_cache_rw` is the state below. cache.rs prepends the material records
// (`nmat_cache_records`, a uniform block: read by every lookup, they never change) and
// cache_lookup.wgsl follows this file.
//
// The state (NMAT_CACHE_STATE_*, generated from nmat-wgpu's layout.rs like every layout these
// passes read): the free slots, the new tiles (marked this frame and not cached), the new tiles
// given a slot; from NMAT_CACHE_STATE_WORDS the free slots (a stack), then the new tiles' pages
// (as many as slots), then per material its decode queue (NMAT_CACHE_QUEUE_*, then an entry per
// tile, NMAT_CACHE_ENTRY_*: its slot and mip << 26 | row << 13 | column).
// The dispatch arguments (their own buffer: a dispatch may not read its arguments from a buffer
// it writes), bound in place of the codes in the plan and finish passes, which write them:
// NMAT_CACHE_ARGS_* (the allocate and clear passes), then per material NMAT_CACHE_DECODE_* (its
// decode with one, two and four workgroups per new tile), each a NMAT_CACHE_DISPATCH_* (x, y, z).

@group(0) @binding(0) var<storage, read_write> nmat_cache_table: array<atomic<u32>>;
@group(0) @binding(1) var<storage, read_write> nmat_cache_rw: array<atomic<u32>>;
@group(0) @binding(2) var<storage, read> nmat_cache_lookups: array<u32>;
// The codes (the dispatch arguments in the plan and finish passes).
@group(0) @binding(3) var<storage, read_write> nmat_cache_codes: array<atomic<u32>>;
@group(0) @binding(4) var<uniform> nmat_cache_params: NmatCacheParams;

const NMAT_CACHE_MAX_GROUPS: u32 = 65535u;

fn nmat_cache_word(i: u32) -> u32 {
    return atomicLoad(&nmat_cache_table[i]);
}

// (cache_sample.wgsl's reader needs it; no pass of this module reads codes: the resolve pass
// has its own module, with the codes read-only.)
fn nmat_cache_code_word(i: u32) -> u32 {
    return atomicLoad(&nmat_cache_codes[i]);
}

// The mark pass runs the filter with a fetch that marks tiles instead of reading them: it marks
// exactly the texels' tiles a lookup reads. A lookup's taps mostly share a page: the last page
// it marked is not loaded again (0, the table's first word, is never a page).
var<private> nmat_cache_marked_page: u32;

fn nmat_fetch(x: i32, y: i32, mip: u32, mask: u32) {
    let page = nmat_cache_page(x, y, mip).x;
    if (page == nmat_cache_marked_page) {
        return;
    }
    nmat_cache_marked_page = page;
    if ((atomicLoad(&nmat_cache_table[page]) & NMAT_CACHE_MARK) != 0u) {
        return;
    }
    let old = atomicOr(&nmat_cache_table[page], NMAT_CACHE_MARK);
    if ((old & NMAT_CACHE_MARK) == 0u) {
        atomicAdd(&nmat_cache_table[NMAT_CACHE_MARKED], 1u);
        if (old != 0u) {
            atomicAdd(&nmat_cache_table[NMAT_CACHE_HITS], 1u);
        }
    }
}

fn nmat_cache_slots() -> u32 {
    return nmat_cache_word(NMAT_CACHE_SLOTS);
}

fn nmat_cache_new_at() -> u32 {
    return NMAT_CACHE_STATE_WORDS + nmat_cache_slots();
}

fn nmat_cache_queue_at(material: u32) -> u32 {
    let queue_words = NMAT_CACHE_QUEUE_WORDS + NMAT_CACHE_ENTRY_WORDS * nmat_cache_slots();
    return NMAT_CACHE_STATE_WORDS + 2u * nmat_cache_slots() + material * queue_words;
}

// The indirect dispatch of `groups` workgroups at word `at` of the arguments (over y past the
// limit).
fn nmat_cache_dispatch(at: u32, groups: u32) {
    let x = min(groups, NMAT_CACHE_MAX_GROUPS);
    atomicStore(&nmat_cache_codes[at + NMAT_CACHE_DISPATCH_X], x);
    let y = select((groups + x - 1u) / max(x, 1u), 1u, groups == 0u);
    atomicStore(&nmat_cache_codes[at + NMAT_CACHE_DISPATCH_Y], y);
    atomicStore(&nmat_cache_codes[at + NMAT_CACHE_DISPATCH_Z], 1u);
}

// Marks the tiles each lookup reads (one invocation per lookup); counts marked tiles and hits.
@compute @workgroup_size(64)
fn nmat_cache_mark(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = nmat_cache_index(id, groups);
    if (i >= nmat_cache_params.count) {
        return;
    }
    _ = nmat_cache_lookup(i);
}

// One invocation per page: a marked page not cached joins the new tiles; a cached page the frame
// did not mark is evicted (its slot freed); the marks are cleared.
@compute @workgroup_size(64)
fn nmat_cache_compact(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = nmat_cache_index(id, groups);
    if (i >= nmat_cache_word(NMAT_CACHE_PAGES)) {
        return;
    }
    let page = nmat_cache_word(NMAT_CACHE_PAGES_AT) + i;
    let v = atomicLoad(&nmat_cache_table[page]);
    if (v == 0u) {
        return;
    }
    let slot = v & ~NMAT_CACHE_MARK;
    if (v == NMAT_CACHE_MARK) {
        let q = atomicAdd(&nmat_cache_rw[NMAT_CACHE_STATE_NEW], 1u);
        if (q < nmat_cache_slots()) {
            atomicStore(&nmat_cache_rw[nmat_cache_new_at() + q], page);
        }
    } else if ((v & NMAT_CACHE_MARK) == 0u) {
        let f = atomicAdd(&nmat_cache_rw[NMAT_CACHE_STATE_FREE], 1u);
        atomicStore(&nmat_cache_rw[NMAT_CACHE_STATE_WORDS + f], slot - 1u);
        atomicAdd(&nmat_cache_table[NMAT_CACHE_EVICTED], 1u);
        atomicStore(&nmat_cache_table[page], 0u);
        return;
    }
    atomicStore(&nmat_cache_table[page], slot);
}

// One invocation: the allocate pass's dispatch; every decode queue emptied.
@compute @workgroup_size(1)
fn nmat_cache_plan() {
    let n = min(atomicLoad(&nmat_cache_rw[NMAT_CACHE_STATE_NEW]), nmat_cache_slots());
    nmat_cache_dispatch(NMAT_CACHE_ARGS_ALLOCATE, (n + 63u) / 64u);
    for (var k = 0u; k < nmat_cache_word(NMAT_CACHE_MATERIALS); k++) {
        atomicStore(&nmat_cache_rw[nmat_cache_queue_at(k) + NMAT_CACHE_QUEUE_COUNT], 0u);
    }
}

// One invocation per new tile: the next free slot (none: the tile overflows, counted by finish),
// and a place in its material's decode queue.
@compute @workgroup_size(64)
fn nmat_cache_allocate(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = nmat_cache_index(id, groups);
    let free = atomicLoad(&nmat_cache_rw[NMAT_CACHE_STATE_FREE]);
    if (i >= min(atomicLoad(&nmat_cache_rw[NMAT_CACHE_STATE_NEW]), free)) {
        return;
    }
    let slot = atomicLoad(&nmat_cache_rw[NMAT_CACHE_STATE_WORDS + free - 1u - i]);
    let page = atomicLoad(&nmat_cache_rw[nmat_cache_new_at() + i]);
    atomicStore(&nmat_cache_table[page], slot + 1u);
    // The page's mip: the last range starting at or before it (binary search).
    let ranges_at = nmat_cache_word(NMAT_CACHE_RANGES_AT);
    var lo = 0u;
    var hi = nmat_cache_word(NMAT_CACHE_RANGES);
    while (hi - lo > 1u) {
        let mid = (lo + hi) / 2u;
        if (nmat_cache_word(ranges_at + NMAT_CACHE_SPAN_WORDS * mid + NMAT_CACHE_SPAN_FIRST_PAGE) <= page) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let span = ranges_at + NMAT_CACHE_SPAN_WORDS * lo;
    let first = nmat_cache_word(span + NMAT_CACHE_SPAN_FIRST_PAGE);
    let which = nmat_cache_word(span + NMAT_CACHE_SPAN_WHICH);
    nmat_cache_material = which >> 8u;
    let mip = which & 255u;
    let size = nmat_mip_size(mip);
    let columns = (size.x + 15u) / 16u;
    let tx = (page - first) % columns;
    let ty = (page - first) / columns;
    let q = nmat_cache_queue_at(nmat_cache_material);
    let at = atomicAdd(&nmat_cache_rw[q + NMAT_CACHE_QUEUE_COUNT], 1u);
    let entry = q + NMAT_CACHE_QUEUE_WORDS + NMAT_CACHE_ENTRY_WORDS * at;
    atomicStore(&nmat_cache_rw[entry + NMAT_CACHE_ENTRY_SLOT], slot);
    atomicStore(&nmat_cache_rw[entry + NMAT_CACHE_ENTRY_KEY], (mip << 26u) | (ty << 13u) | tx);
    let texels = min(16u, size.x - 16u * tx) * min(16u, size.y - 16u * ty);
    atomicAdd(&nmat_cache_table[NMAT_CACHE_DECODED_TEXELS], texels);
}

// One invocation: the slots taken, the tiles decoded and overflowed, the clear and decode
// dispatches.
@compute @workgroup_size(1)
fn nmat_cache_finish() {
    let free = atomicLoad(&nmat_cache_rw[NMAT_CACHE_STATE_FREE]);
    let wanted = atomicLoad(&nmat_cache_rw[NMAT_CACHE_STATE_NEW]);
    let given = min(wanted, free);
    atomicStore(&nmat_cache_rw[NMAT_CACHE_STATE_FREE], free - given);
    atomicStore(&nmat_cache_rw[NMAT_CACHE_STATE_GIVEN], given);
    atomicStore(&nmat_cache_table[NMAT_CACHE_DECODED], given);
    atomicAdd(&nmat_cache_table[NMAT_CACHE_OVERFLOWED], wanted - given);
    nmat_cache_dispatch(NMAT_CACHE_ARGS_CLEAR, given);
    for (var k = 0u; k < nmat_cache_word(NMAT_CACHE_MATERIALS); k++) {
        let count = atomicLoad(&nmat_cache_rw[nmat_cache_queue_at(k) + NMAT_CACHE_QUEUE_COUNT]);
        let args = NMAT_CACHE_ARGS_WORDS + NMAT_CACHE_DECODE_WORDS * k;
        nmat_cache_dispatch(args + NMAT_CACHE_DECODE_ONE, count);
        nmat_cache_dispatch(args + NMAT_CACHE_DECODE_TWO, 2u * count);
        nmat_cache_dispatch(args + NMAT_CACHE_DECODE_FOUR, 4u * count);
    }
}

// One workgroup per new tile given a slot: the slot's words zeroed (decoding ORs its bytes in).
@compute @workgroup_size(64)
fn nmat_cache_clear(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let g = wg.x + wg.y * groups.x;
    if (g >= atomicLoad(&nmat_cache_rw[NMAT_CACHE_STATE_GIVEN])) {
        return;
    }
    let page = atomicLoad(&nmat_cache_rw[nmat_cache_new_at() + g]);
    let words = nmat_cache_word(NMAT_CACHE_SLOT_WORDS);
    let first = ((nmat_cache_word(page) & ~NMAT_CACHE_MARK) - 1u) * words;
    for (var w = lid; w < words; w += 64u) {
        atomicStore(&nmat_cache_codes[first + w], 0u);
    }
}
