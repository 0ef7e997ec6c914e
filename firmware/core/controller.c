#include "controller.h"
#include <string.h>
#include "crc32.h"
#include "le.h"

/* The transfer bitmap: bit i % 8 of byte i / 8 is set once data byte i of the table arrived. */
#define XFER_BIT(i) ((uint8_t)(1u << ((i) % 8u)))
#define XFER_ALL_EIGHT 0xFFu

static uint16_t capacity(const fw_controller *c) { return c->cfg.n_pixels; }

static int load_active(fw_controller *c)
{
    if (c->active_bank == FW_NO_BANK)
        return 0;
    uint32_t n = (uint32_t)c->active.n_tables * FW_TABLE_BYTES;
    uint8_t piece[64];
    for (uint32_t done = 0; done < n; done += sizeof piece) {
        int rc = fw_bank_read_data(c->hal, capacity(c), c->active_bank, done, piece, sizeof piece);
        if (rc < 0)
            return rc;
        for (uint32_t i = 0; i < sizeof piece; i += 2) {
            uint32_t e = (done + i) / 2u;
            c->table[e / FW_TABLE_ENTRIES][e % FW_TABLE_ENTRIES] = fw_get16(piece + i);
        }
    }
    return 0;
}

int fw_boot(fw_controller *c, const fw_hal *hal, const fw_config *cfg)
{
    if (cfg->address < FW_MIN_ADDRESS || cfg->address > FW_MAX_ADDRESS || cfg->n_pixels < 1
        || cfg->n_pixels > FW_MAX_PIXELS || cfg->max_chunk < 1 || cfg->max_chunk > FW_MAX_CHUNK_DATA)
        return -1;
    c->hal = hal;
    c->cfg = *cfg;
    fw_rx_reset(&c->rx);
    c->active_bank = fw_banks_select(hal, capacity(c), &c->active);
    if (load_active(c) < 0)
        c->active_bank = FW_NO_BANK;
    c->xfer_open = 0;
    c->last_valid = 0;
    fw_motors_init(&c->motors, hal, cfg->n_pixels);
    fw_pattern_boot(&c->pattern, &c->motors, cfg->n_pixels);
    fw_latch_boot(&c->latch);
    return 0;
}

/* ---- answers --------------------------------------------------------------------------- */

static fw_msg ack(uint8_t request_type)
{
    fw_msg m = {.type = FW_ACK};
    m.u.ack.request_type = request_type;
    return m;
}

static fw_msg nak(uint8_t request_type, uint8_t error, uint32_t detail)
{
    fw_msg m = {.type = FW_NAK};
    m.u.nak.request_type = request_type;
    m.u.nak.error = error;
    m.u.nak.detail = detail;
    return m;
}

/* ---- handlers -------------------------------------------------------------------------- */

static fw_msg on_hello(fw_controller *c)
{
    fw_msg m = {.type = FW_INFO};
    m.u.info = (fw_info){FW_PROTOCOL_VERSION, FW_VERSION_MAJOR, FW_VERSION_MINOR,
                         FW_VERSION_PATCH, c->cfg.uid, c->cfg.n_pixels, capacity(c),
                         c->cfg.max_chunk, c->cfg.max_length_um,
                         FW_FEATURE_PATTERNS | FW_FEATURE_LATCH};
    return m;
}

static fw_msg on_status(fw_controller *c)
{
    fw_msg m = {.type = FW_TABLE_STATUS};
    fw_table_status *s = &m.u.table_status;
    s->active_bank = FW_NO_BANK;
    if (c->active_bank != FW_NO_BANK) {
        s->active_bank = c->active_bank;
        s->kind = c->active.kind;
        s->n_tables = c->active.n_tables;
        s->table_id = c->active.table_id;
        s->table_crc = c->active.data_crc;
        s->generation = c->active.generation;
    }
    s->staging = c->xfer_open;
    s->staged_bytes = c->xfer_open ? c->xfer_received : 0;
    return m;
}

static fw_msg on_begin(fw_controller *c, const fw_table_begin *b)
{
    int ok = (b->kind == FW_KIND_GLOBAL && b->n_tables == 1)
             || (b->kind == FW_KIND_PER_PIXEL && b->n_tables == c->cfg.n_pixels);
    if (!ok || b->total_bytes != (uint32_t)b->n_tables * FW_TABLE_BYTES)
        return nak(FW_TABLE_BEGIN, FW_NAK_BAD_KIND, c->cfg.n_pixels);
    if (b->n_tables > capacity(c))
        return nak(FW_TABLE_BEGIN, FW_NAK_TOO_LARGE, capacity(c));
    const fw_table_begin *x = &c->xfer;
    if (c->xfer_open && x->table_id == b->table_id && x->kind == b->kind
        && x->n_tables == b->n_tables && x->total_bytes == b->total_bytes
        && x->table_crc == b->table_crc)
        return ack(FW_TABLE_BEGIN);   /* retransmitted BEGIN: keep what has arrived */
    uint8_t bank = c->active_bank == 0 ? 1 : 0;
    c->xfer_open = 0;
    if (fw_bank_invalidate(c->hal, capacity(c), bank) < 0)
        return nak(FW_TABLE_BEGIN, FW_NAK_STORAGE_FAILED, 0);
    c->xfer = *b;
    c->xfer_bank = bank;
    c->xfer_received = 0;
    memset(c->xfer_map, 0, (b->total_bytes + 7u) / 8u);
    c->xfer_open = 1;
    return ack(FW_TABLE_BEGIN);
}

static fw_msg on_chunk(fw_controller *c, const fw_table_chunk *k)
{
    if (!c->xfer_open || c->xfer.table_id != k->table_id)
        return nak(FW_TABLE_CHUNK, FW_NAK_NO_TRANSFER, 0);
    if (k->data_len > c->cfg.max_chunk)
        return nak(FW_TABLE_CHUNK, FW_NAK_TOO_LARGE, c->cfg.max_chunk);
    if ((uint64_t)k->offset + k->data_len > c->xfer.total_bytes)
        return nak(FW_TABLE_CHUNK, FW_NAK_OUT_OF_RANGE, c->xfer.total_bytes);
    if (fw_bank_write_data(c->hal, capacity(c), c->xfer_bank, k->offset, k->data, k->data_len) < 0)
        return nak(FW_TABLE_CHUNK, FW_NAK_STORAGE_FAILED, 0);
    for (uint32_t i = k->offset; i < k->offset + k->data_len; i++) {
        uint8_t bit = XFER_BIT(i);
        if (!(c->xfer_map[i / 8u] & bit)) {
            c->xfer_map[i / 8u] |= bit;
            c->xfer_received++;
        }
    }
    return ack(FW_TABLE_CHUNK);
}

static uint32_t first_missing(const fw_controller *c)
{
    uint32_t total = c->xfer.total_bytes;
    for (uint32_t i = 0; i < total; i += 8) {
        uint8_t byte = c->xfer_map[i / 8u];
        if (byte != XFER_ALL_EIGHT)
            for (uint32_t j = i; j < i + 8 && j < total; j++)
                if (!(byte & XFER_BIT(j)))
                    return j;
    }
    return total;
}

static fw_msg on_commit(fw_controller *c, const fw_table_commit *m)
{
    if (!c->xfer_open) {
        if (c->active_bank != FW_NO_BANK && c->active.table_id == m->table_id
            && c->active.data_crc == m->table_crc)
            return ack(FW_TABLE_COMMIT);   /* committed before; only the ACK was lost */
        return nak(FW_TABLE_COMMIT, FW_NAK_NO_TRANSFER, 0);
    }
    const fw_table_begin *b = &c->xfer;
    if (b->table_id != m->table_id || b->table_crc != m->table_crc)
        return nak(FW_TABLE_COMMIT, FW_NAK_NO_TRANSFER, 0);
    if (c->xfer_received < b->total_bytes)
        return nak(FW_TABLE_COMMIT, FW_NAK_INCOMPLETE, first_missing(c));
    uint32_t crc, over;
    if (fw_bank_scan(c->hal, capacity(c), c->xfer_bank, b->total_bytes, &crc,
                     &c->cfg.max_length_um, &over) < 0)
        return nak(FW_TABLE_COMMIT, FW_NAK_STORAGE_FAILED, 0);
    if (crc != b->table_crc) {
        c->xfer_open = 0;
        return nak(FW_TABLE_COMMIT, FW_NAK_CRC_MISMATCH, crc);
    }
    if (over != FW_NONE_OVER) {
        c->xfer_open = 0;
        return nak(FW_TABLE_COMMIT, FW_NAK_VALUE_RANGE, over);
    }
    fw_bank_header h = {c->active_bank != FW_NO_BANK ? c->active.generation + 1u : 1u,
                        b->table_id, b->kind, b->n_tables, b->table_crc};
    if (fw_bank_write_header(c->hal, capacity(c), c->xfer_bank, &h) < 0)   /* the switch */
        return nak(FW_TABLE_COMMIT, FW_NAK_STORAGE_FAILED, 0);
    c->active_bank = c->xfer_bank;
    c->active = h;
    c->xfer_open = 0;
    if (load_active(c) < 0) {   /* the new table is committed but cannot be read back */
        c->active_bank = FW_NO_BANK;
        return nak(FW_TABLE_COMMIT, FW_NAK_STORAGE_FAILED, 0);
    }
    return ack(FW_TABLE_COMMIT);
}

/* Normal display of pixel p becomes table[level], the table active now. */
static void show_level(fw_controller *c, uint16_t p, uint8_t level)
{
    uint16_t t = c->active.kind == FW_KIND_PER_PIXEL && p < c->active.n_tables ? p : 0;
    fw_pattern_set_normal(&c->pattern, &c->motors, p, c->table[t][level]);
}

static fw_msg on_set_level(fw_controller *c, const fw_set_level *s)
{
    uint16_t n = c->cfg.n_pixels;
    if ((uint32_t)s->first_pixel + s->levels_len > n)
        return nak(FW_SET_LEVEL, FW_NAK_BAD_PIXEL, n);
    if (c->active_bank == FW_NO_BANK)
        return nak(FW_SET_LEVEL, FW_NAK_NO_TABLE, 0);
    for (uint16_t i = 0; i < s->levels_len; i++)
        show_level(c, (uint16_t)(s->first_pixel + i), s->levels[i]);
    return ack(FW_SET_LEVEL);
}

static fw_msg on_stage_level(fw_controller *c, const fw_stage_level *s)
{
    uint16_t n = c->cfg.n_pixels;
    if ((uint32_t)s->first_pixel + s->levels_len > n)
        return nak(FW_STAGE_LEVEL, FW_NAK_BAD_PIXEL, n);
    if (c->active_bank == FW_NO_BANK)
        return nak(FW_STAGE_LEVEL, FW_NAK_NO_TABLE, 0);
    fw_latch_stage(&c->latch, s->frame, s->first_pixel, s->levels, s->levels_len);
    return ack(FW_STAGE_LEVEL);
}

/* SHOW: the staged pixels of that frame take their levels through the table active now. */
static fw_msg on_show(fw_controller *c, const fw_show *s)
{
    if (fw_latch_take(&c->latch, s->frame) && c->active_bank != FW_NO_BANK)
        for (uint16_t p = 0; p < c->cfg.n_pixels; p++)
            if (fw_latch_has(&c->latch, p))
                show_level(c, p, c->latch.level[p]);
    fw_latch_clear(&c->latch);
    return ack(FW_SHOW);
}

/* A frame to every controller: a valid SHOW is carried out, anything else ignored. */
static void on_broadcast(fw_controller *c, const uint8_t *body, size_t n)
{
    fw_msg req;
    if (body[FW_HEADER_VERSION] == FW_PROTOCOL_VERSION && body[FW_HEADER_TYPE] == FW_SHOW
        && fw_msg_unpack(FW_SHOW, body + FW_HEADER_SIZE, n - FW_HEADER_SIZE, &req) == FW_MSG_OK)
        (void)on_show(c, &req.u.show);
}

static fw_msg on_pattern(fw_controller *c, const fw_pattern *p)
{
    uint32_t detail = 0;
    int error = fw_pattern_show(&c->pattern, &c->motors, p, c->cfg.n_pixels,
                                c->cfg.max_length_um, c->hal->millis(c->hal->ctx), &detail);
    return error ? nak(FW_PATTERN, (uint8_t)error, detail) : ack(FW_PATTERN);
}

static fw_msg on_pattern_end(fw_controller *c)
{
    fw_pattern_end(&c->pattern, &c->motors, c->cfg.n_pixels);
    return ack(FW_PATTERN_END);
}

/* POSITIONS is built in place in c->wire; returns the payload length, or 0 with *refusal set. */
static size_t on_get_positions(fw_controller *c, const fw_get_positions *g, uint8_t *payload,
                               fw_msg *refusal)
{
    uint16_t n = c->cfg.n_pixels;
    if (g->count < 1 || g->count > FW_MAX_POSITIONS) {
        *refusal = nak(FW_GET_POSITIONS, FW_NAK_BAD_PAYLOAD, g->count);
        return 0;
    }
    if ((uint32_t)g->first_pixel + g->count > n) {
        *refusal = nak(FW_GET_POSITIONS, FW_NAK_BAD_PIXEL, n);
        return 0;
    }
    fw_put16(payload, g->first_pixel);
    for (uint16_t i = 0; i < g->count; i++) {
        uint16_t p = (uint16_t)(g->first_pixel + i);
        uint16_t target_um;
        fw_put16(payload + 2 + 4 * i, fw_motor_position(&c->motors, c->hal, p, &target_um));
        fw_put16(payload + 4 + 4 * i, target_um);
    }
    return 2u + 4u * g->count;
}

/* ---- dispatch -------------------------------------------------------------------------- */

size_t fw_handle_body(fw_controller *c, const uint8_t *body, size_t n)
{
    fw_poll(c);   /* a pattern whose watchdog ran out ends before this frame */
    if (n < FW_HEADER_SIZE)
        return 0;
    uint8_t version = body[FW_HEADER_VERSION], address = body[FW_HEADER_ADDRESS];
    uint8_t type = body[FW_HEADER_TYPE];
    uint16_t seq = fw_get16(body + FW_HEADER_SEQ);
    if (address == FW_BROADCAST_ADDRESS && !(type & FW_TYPE_RESPONSE)) {
        on_broadcast(c, body, n);
        return 0;
    }
    if (address != c->cfg.address || (type & FW_TYPE_RESPONSE))
        return 0;
    uint32_t crc = fw_crc32(body, n);
    if (c->last_valid && c->last_seq == seq && c->last_crc == crc) {
        c->hal->tx(c->hal->ctx, c->wire, c->last_len);   /* a retransmission: same answer */
        return c->last_len;
    }
    const uint8_t *payload = body + FW_HEADER_SIZE;
    size_t plen = n - FW_HEADER_SIZE;
    uint8_t *out = c->wire + FW_WIRE_SLACK;   /* the answer's body */
    size_t out_payload = 0;
    fw_msg req, ans;
    c->last_valid = 0;   /* c->wire is about to be overwritten */
    if (version != FW_PROTOCOL_VERSION) {
        ans = nak(type, FW_NAK_UNSUPPORTED_VERSION, FW_PROTOCOL_VERSION);
    } else {
        int rc = fw_msg_unpack(type, payload, plen, &req);
        if (rc != FW_MSG_OK) {
            ans = nak(type, rc == FW_MSG_UNKNOWN_TYPE ? FW_NAK_UNKNOWN_TYPE : FW_NAK_BAD_PAYLOAD,
                      (uint32_t)plen);
        } else {
            switch (type) {
            case FW_HELLO: ans = on_hello(c); break;
            case FW_GET_STATUS: ans = on_status(c); break;
            case FW_TABLE_BEGIN: ans = on_begin(c, &req.u.table_begin); break;
            case FW_TABLE_CHUNK: ans = on_chunk(c, &req.u.table_chunk); break;
            case FW_TABLE_COMMIT: ans = on_commit(c, &req.u.table_commit); break;
            case FW_SET_LEVEL: ans = on_set_level(c, &req.u.set_level); break;
            case FW_PATTERN: ans = on_pattern(c, &req.u.pattern); break;
            case FW_PATTERN_END: ans = on_pattern_end(c); break;
            case FW_STAGE_LEVEL: ans = on_stage_level(c, &req.u.stage_level); break;
            case FW_SHOW: ans = on_show(c, &req.u.show); break;
            case FW_GET_POSITIONS:
                out_payload = on_get_positions(c, &req.u.get_positions, out + FW_HEADER_SIZE, &ans);
                if (out_payload)
                    ans.type = FW_POSITIONS;
                break;
            default:   /* a response type cannot get here (bit 7 is filtered above) */
                ans = nak(type, FW_NAK_UNKNOWN_TYPE, (uint32_t)plen);
                break;
            }
        }
    }
    if (ans.type != FW_POSITIONS)
        out_payload = fw_msg_pack(&ans, out + FW_HEADER_SIZE);
    fw_put_header(out, FW_PROTOCOL_VERSION, c->cfg.address, ans.type, seq);
    c->last_len = (uint16_t)fw_frame_wrap(c->wire, FW_HEADER_SIZE + out_payload);
    c->last_seq = seq;
    c->last_crc = crc;
    c->last_valid = 1;
    c->hal->tx(c->hal->ctx, c->wire, c->last_len);
    return c->last_len;
}

int fw_rx_feed(fw_controller *c, const uint8_t *data, size_t n)
{
    int type = FW_RX_NO_FRAME;
    for (size_t i = 0; i < n; i++) {
        size_t body = fw_rx_byte(&c->rx, data[i]);
        if (body) {
            type = c->rx.buf[FW_HEADER_TYPE];
            fw_handle_body(c, c->rx.buf, body);
        }
    }
    return type;
}

int fw_poll(fw_controller *c)
{
    return fw_pattern_poll(&c->pattern, &c->motors, c->cfg.n_pixels, c->hal->millis(c->hal->ctx));
}

uint16_t fw_target_um(const fw_controller *c, uint16_t p)
{
    return c->motors.target_um[p];   /* only the main context writes it */
}

void fw_tick(fw_controller *c)
{
    fw_motors_tick(&c->motors, c->hal, c->cfg.n_pixels);
}
