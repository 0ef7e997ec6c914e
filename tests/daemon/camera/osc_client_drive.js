// Drives an OSC camera with a third-party client, osc-client (npm, MIT, BublTechnology), as
// its README does; prints one JSON object with every answer it got.
// Usage: node osc_client_drive.js HOST PORT   (NODE_PATH naming the node_modules holding it)
'use strict'

const { Osc2Client } = require('osc-client')

const [host, port] = process.argv.slice(2)
const client = new Osc2Client(host, port)

// An OscError's code and message (the client rejects with one for every state "error").
async function refusal (promise) {
  try {
    return { answered: await promise }
  } catch (err) {
    return { code: err.oscCode, message: err.oscMessage }
  }
}

async function main () {
  const out = {}
  out.info = await client.getInfo()
  out.state = await client.getState()
  out.pictureBefore = await refusal(client.takePicture())
  out.setOptions = await client.setOptions(undefined, { captureMode: 'image' })
  out.getOptions = await client.getOptions(undefined, [
    'captureMode', 'exposureCompensation', 'iso', 'captureModeSupport'])
  out.unknownOption = await refusal(client.getOptions(undefined, ['noSuchOption']))
  out.takePicture = await client.takePicture() // inProgress, polled on /osc/commands/status
  out.listFiles = await client.listFiles('image', 10, 0)
  out.delete = await client.delete2([out.takePicture.results.fileUrl])
  out.listFilesAfter = await client.listFiles('image', 10, 0)
  out.unknownCommand = await refusal(client.startSession())
  return out
}

main().then(
  (out) => process.stdout.write(JSON.stringify(out) + '\n'),
  (err) => { process.stderr.write(`${err && err.stack ? err.stack : err}\n`); process.exit(1) })
