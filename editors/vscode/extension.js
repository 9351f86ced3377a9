// Starts `bondc lsp` (the command in the setting bondc.command) for .bg files.
const vscode = require("vscode");
const { LanguageClient, TransportKind } = require("vscode-languageclient/node");

let client;

function activate(context) {
  const command = vscode.workspace.getConfiguration("bondc").get("command", ["bondc", "lsp"]);
  const server = { command: command[0], args: command.slice(1), transport: TransportKind.stdio };
  client = new LanguageClient("bondc", "bondc", server, {
    documentSelector: [{ scheme: "file", language: "bondgraph" }, { scheme: "untitled", language: "bondgraph" }],
  });
  client.start();
  context.subscriptions.push({ dispose: () => client && client.stop() });
}

function deactivate() {
  return client ? client.stop() : undefined;
}

module.exports = { activate, deactivate };
