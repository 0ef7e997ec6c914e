#include "msg.h"
#include <string.h>
#include "le.h"

/* Payload size of each type's fixed part, and the bounds of its byte tail (0, 0: none). */
typedef struct { uint8_t type; uint8_t fixed; uint16_t tail_min, tail_max; uint8_t step; } layout;

static const layout layouts[] = {
    {FW_HELLO, 0, 0, 0, 0},          {FW_GET_STATUS, 0, 0, 0, 0},
    {FW_TABLE_BEGIN, 15, 0, 0, 0},   {FW_TABLE_CHUNK, 8, 1, FW_MAX_CHUNK_DATA, 1},
    {FW_TABLE_COMMIT, 8, 0, 0, 0},   {FW_SET_LEVEL, 2, 1, FW_MAX_PAYLOAD - 2u, 1},
    {FW_GET_POSITIONS, 4, 0, 0, 0},  {FW_PATTERN, 4, 2, 2u * FW_MAX_PATTERN_PIXELS, 2},
    {FW_PATTERN_END, 0, 0, 0, 0},    {FW_STAGE_LEVEL, 4, 1, FW_MAX_STAGE_PIXELS, 1},
    {FW_SHOW, 2, 0, 0, 0},           {FW_INFO, 18, 0, 0, 0},
    {FW_TABLE_STATUS, 21, 0, 0, 0},  {FW_POSITIONS, 2, 0, 4u * FW_MAX_POSITIONS, 4},
    {FW_ACK, 1, 0, 0, 0},            {FW_NAK, 6, 0, 0, 0},
};

static const layout *find(uint8_t type)
{
    for (size_t i = 0; i < sizeof layouts / sizeof layouts[0]; i++)
        if (layouts[i].type == type)
            return &layouts[i];
    return NULL;
}

int fw_msg_unpack(uint8_t type, const uint8_t *p, size_t n, fw_msg *m)
{
    const layout *l = find(type);
    if (l == NULL)
        return FW_MSG_UNKNOWN_TYPE;
    if (l->step == 0) {
        if (n != l->fixed)
            return FW_MSG_BAD_PAYLOAD;
    } else {
        if (n < l->fixed)
            return FW_MSG_BAD_PAYLOAD;
        size_t t = n - l->fixed;
        if (t < l->tail_min || t > l->tail_max || t % l->step)
            return FW_MSG_BAD_PAYLOAD;
    }
    uint16_t tail_len = (uint16_t)(n - l->fixed);
    memset(m, 0, sizeof *m);
    m->type = type;
    switch (type) {
    case FW_INFO: {
        fw_info *x = &m->u.info;
        x->protocol_version = p[0]; x->fw_major = p[1]; x->fw_minor = p[2]; x->fw_patch = p[3];
        x->uid = fw_get32(p + 4); x->n_pixels = fw_get16(p + 8);
        x->table_capacity = fw_get16(p + 10); x->max_chunk = fw_get16(p + 12);
        x->max_length_um = fw_get16(p + 14); x->features = fw_get16(p + 16);
        break;
    }
    case FW_TABLE_STATUS: {
        fw_table_status *x = &m->u.table_status;
        x->active_bank = p[0]; x->kind = p[1]; x->n_tables = fw_get16(p + 2);
        x->table_id = fw_get32(p + 4); x->table_crc = fw_get32(p + 8);
        x->generation = fw_get32(p + 12); x->staging = p[16]; x->staged_bytes = fw_get32(p + 17);
        break;
    }
    case FW_TABLE_BEGIN: {
        fw_table_begin *x = &m->u.table_begin;
        x->table_id = fw_get32(p); x->kind = p[4]; x->n_tables = fw_get16(p + 5);
        x->total_bytes = fw_get32(p + 7); x->table_crc = fw_get32(p + 11);
        break;
    }
    case FW_TABLE_CHUNK:
        m->u.table_chunk.table_id = fw_get32(p);
        m->u.table_chunk.offset = fw_get32(p + 4);
        m->u.table_chunk.data = p + 8;
        m->u.table_chunk.data_len = tail_len;
        break;
    case FW_TABLE_COMMIT:
        m->u.table_commit.table_id = fw_get32(p);
        m->u.table_commit.table_crc = fw_get32(p + 4);
        break;
    case FW_SET_LEVEL:
        m->u.set_level.first_pixel = fw_get16(p);
        m->u.set_level.levels = p + 2;
        m->u.set_level.levels_len = tail_len;
        break;
    case FW_GET_POSITIONS:
        m->u.get_positions.first_pixel = fw_get16(p);
        m->u.get_positions.count = fw_get16(p + 2);
        break;
    case FW_PATTERN:
        m->u.pattern.timeout_ds = fw_get16(p);
        m->u.pattern.first_pixel = fw_get16(p + 2);
        m->u.pattern.lengths = p + 4;
        m->u.pattern.lengths_len = tail_len;
        break;
    case FW_STAGE_LEVEL:
        m->u.stage_level.frame = fw_get16(p);
        m->u.stage_level.first_pixel = fw_get16(p + 2);
        m->u.stage_level.levels = p + 4;
        m->u.stage_level.levels_len = tail_len;
        break;
    case FW_SHOW:
        m->u.show.frame = fw_get16(p);
        break;
    case FW_POSITIONS:
        m->u.positions.first_pixel = fw_get16(p);
        m->u.positions.positions = p + 2;
        m->u.positions.positions_len = tail_len;
        break;
    case FW_ACK:
        m->u.ack.request_type = p[0];
        break;
    case FW_NAK:
        m->u.nak.request_type = p[0]; m->u.nak.error = p[1]; m->u.nak.detail = fw_get32(p + 2);
        break;
    default:   /* HELLO, GET_STATUS, PATTERN_END: empty */
        break;
    }
    return FW_MSG_OK;
}

size_t fw_msg_pack(const fw_msg *m, uint8_t *p)
{
    switch (m->type) {
    case FW_INFO: {
        const fw_info *x = &m->u.info;
        p[0] = x->protocol_version; p[1] = x->fw_major; p[2] = x->fw_minor; p[3] = x->fw_patch;
        fw_put32(p + 4, x->uid); fw_put16(p + 8, x->n_pixels); fw_put16(p + 10, x->table_capacity);
        fw_put16(p + 12, x->max_chunk); fw_put16(p + 14, x->max_length_um);
        fw_put16(p + 16, x->features);
        return 18;
    }
    case FW_TABLE_STATUS: {
        const fw_table_status *x = &m->u.table_status;
        p[0] = x->active_bank; p[1] = x->kind; fw_put16(p + 2, x->n_tables);
        fw_put32(p + 4, x->table_id); fw_put32(p + 8, x->table_crc);
        fw_put32(p + 12, x->generation); p[16] = x->staging; fw_put32(p + 17, x->staged_bytes);
        return 21;
    }
    case FW_TABLE_BEGIN: {
        const fw_table_begin *x = &m->u.table_begin;
        fw_put32(p, x->table_id); p[4] = x->kind; fw_put16(p + 5, x->n_tables);
        fw_put32(p + 7, x->total_bytes); fw_put32(p + 11, x->table_crc);
        return 15;
    }
    case FW_TABLE_CHUNK:
        fw_put32(p, m->u.table_chunk.table_id);
        fw_put32(p + 4, m->u.table_chunk.offset);
        memcpy(p + 8, m->u.table_chunk.data, m->u.table_chunk.data_len);
        return 8u + m->u.table_chunk.data_len;
    case FW_TABLE_COMMIT:
        fw_put32(p, m->u.table_commit.table_id);
        fw_put32(p + 4, m->u.table_commit.table_crc);
        return 8;
    case FW_SET_LEVEL:
        fw_put16(p, m->u.set_level.first_pixel);
        memcpy(p + 2, m->u.set_level.levels, m->u.set_level.levels_len);
        return 2u + m->u.set_level.levels_len;
    case FW_GET_POSITIONS:
        fw_put16(p, m->u.get_positions.first_pixel);
        fw_put16(p + 2, m->u.get_positions.count);
        return 4;
    case FW_PATTERN:
        fw_put16(p, m->u.pattern.timeout_ds);
        fw_put16(p + 2, m->u.pattern.first_pixel);
        memcpy(p + 4, m->u.pattern.lengths, m->u.pattern.lengths_len);
        return 4u + m->u.pattern.lengths_len;
    case FW_STAGE_LEVEL:
        fw_put16(p, m->u.stage_level.frame);
        fw_put16(p + 2, m->u.stage_level.first_pixel);
        memcpy(p + 4, m->u.stage_level.levels, m->u.stage_level.levels_len);
        return 4u + m->u.stage_level.levels_len;
    case FW_SHOW:
        fw_put16(p, m->u.show.frame);
        return 2;
    case FW_POSITIONS:
        fw_put16(p, m->u.positions.first_pixel);
        memcpy(p + 2, m->u.positions.positions, m->u.positions.positions_len);
        return 2u + m->u.positions.positions_len;
    case FW_ACK:
        p[0] = m->u.ack.request_type;
        return 1;
    case FW_NAK:
        p[0] = m->u.nak.request_type; p[1] = m->u.nak.error; fw_put32(p + 2, m->u.nak.detail);
        return 6;
    default:
        return 0;
    }
}
